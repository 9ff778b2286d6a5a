# pyright: reportConstantRedefinition=false
# (G, J, A are the field's symbols for an integral, a jerk and an acceleration, not constants)
"""The jerk limit as a moving average of the path parameter (FIR), and the raw plan it needs.

The jerk profile plans the path parameter acceleration-limited first (the raw plan: trapezoids,
one speed per 1-D node, continuous over chains of short moves), samples it, and averages it
over a window of N samples spanning T = (N - 1) * period >= max_i a_max_i / j_max_i:

    s_f(t) = mean of s(t - T .. t),  s_f'' = (s'(t) - s'(t - T)) / T,
    s_f''' = (s''(t) - s''(t - T)) / T

so |s_f''| <= A where |s''| <= A, and |s_f'''| <= A / T while the raw acceleration does not
change sign within T (2 A / T where it does). The filtered path parameter is mapped onto the
same blended path: the filter smooths the feed, never the geometry. A full speed change costs
T more than a trapezoid, the time an S-curve of the same A and J adds (A / J), and the raw
plan needs no S-curve per body, so dense short moves keep their feed.

What the raw plan does for the filter:
- a 1-D node that is not a cut inside a chain (a corner blended alone, a stop, the entry and
  exit of a chain) holds its speed v over its blend and T v beyond each end ("extended"): the
  filtered speed is then exactly v over the blend (s_f'' = s_f''' = 0), so a corner is sized
  by its curvature terms alone, and a straight body and its neighbours never share a window;
- a chain's entry (exit) next to a straight move whose far end is held too holds its speed T
  before (after) its blend, on the straight side only (`plan_chains._held_chain_ends`): the
  straight move runs at its own limits, and no window spans its braking and the chain;
- where the raw plan stops (v = 0) it holds still for T, so the filtered plan stops too;
- a body whose speed rises and falls again cruises at its peak for at least T (no sign change
  of s'' within a window); between the bodies of a chain the sign may change, so chain bodies
  get half the jerk budget for s''' (`plan_chains.chain_limits`);
- inside a chain, speed caps and acceleration limits are eroded (`erode`) over the distance a
  window spans: the filtered speed at s is an average of raw speeds within T * v of s.
"""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
from numba import njit

from feed_twin.gcode.profile import CRUISE, HOLD, piece_of_samples


@njit(cache=True)
def _largest(c: float, b: float, A: float) -> float:
    """Largest x >= 0 with x^2 / (2A) + b x <= c (0 when c <= 0)."""
    if c <= 0.0:
        return 0.0
    return A * (-b + math.sqrt(b * b + 2.0 * c / A))


@njit(cache=True)
def plan_speeds_filtered(
    cap: np.ndarray,
    L: np.ndarray,
    A: np.ndarray,
    hold_in: np.ndarray,
    hold_out: np.ndarray,
    v_first: float,
) -> np.ndarray:
    """Boundary speeds of the raw plan: a body i (node i -> i+1) fits
    |v_i^2 - v_i+1^2| / (2 A_i) + h_out_i v_i + h_in_i+1 v_i+1 <= L_i, the node's speed held
    for h_in [s] before its blend and h_out [s] after it (T / 2 each side at extended nodes).
    Each held node's speed is first held to half of either neighbouring body (h v <= L / 2;
    all of it where the body's other end holds nothing there), which keeps every pair
    feasible; then a backward pass of braking bounds and a forward
    pass of speed-ups.

    The braking bound is not monotonic in the next node's speed where that node is held: a
    higher speed there takes more of the body for its hold. A window that goes on from a
    committed one (v_first) may so find the next node's bound below what v_first can brake
    to (a node the committed window saw slower, a hold it saw shorter). The forward pass
    then brakes as far as the body allows (`_braked_to`): to the fastest speed at or below
    the planned one that still leaves room for the next node's hold, else (the body too
    short to brake further) to the slowest speed it can reach: above the node's cap, but
    with s and ds/dt continuous, where the next window's constraints are tighter than the
    committed window's (`plan_profile.speeds_fit` tells; the planner then plans that window
    again with the committed window's decisions, `planner._StreamPlanner._as_decided`)."""
    m = L.shape[0]
    v = cap.copy()
    for i in range(m + 1):
        if i > 0 and hold_in[i] > 0.0:
            share = 0.5 if hold_out[i - 1] > 0.0 else 1.0
            v[i] = min(v[i], share * L[i - 1] / hold_in[i])
        if i < m and hold_out[i] > 0.0:
            share = 0.5 if hold_in[i + 1] > 0.0 else 1.0
            v[i] = min(v[i], share * L[i] / hold_out[i])
    v[0] = v_first
    for i in range(m - 1, 0, -1):
        c = L[i] - hold_in[i + 1] * v[i + 1] + v[i + 1] * v[i + 1] / (2.0 * A[i])
        v[i] = min(v[i], _largest(c, hold_out[i], A[i]))
    for i in range(m):
        c = L[i] - hold_out[i] * v[i] + v[i] * v[i] / (2.0 * A[i])
        v[i + 1] = min(v[i + 1], _largest(c, hold_in[i + 1], A[i]))
        if v[i + 1] < v[i]:
            v[i + 1] = _braked_to(v[i], v[i + 1], L[i], A[i], hold_out[i], hold_in[i + 1])
    return v


BRAKE_SLACK = 1e-12  # relative: a body this much too short still fits (rounding)


@njit(cache=True)
def _braked_to(v0: float, v1: float, L: float, A: float, h0: float, h1: float) -> float:
    """The speed at the end of a braking body (v0 > v1, length L, acceleration A, holds h0 v0
    and h1 v1 at its ends): v1 where (v0^2 - v1^2) / (2A) + h0 v0 + h1 v1 <= L; else the
    lower root of that bound (the body brakes further, to leave room for the hold), or where
    v0 cannot stop within the body the upper one (it brakes as far as the body allows)."""
    excess = (v0 * v0 - v1 * v1) / (2.0 * A) + h0 * v0 + h1 * v1 - L
    if excess <= BRAKE_SLACK * L:
        return v1
    # x^2 - 2 A h1 x - K >= 0 with K = v0^2 + 2 A h0 v0 - 2 A L; roots A h1 -+ sqrt(...)
    K = v0 * v0 + 2.0 * A * (h0 * v0 - L)
    root = math.sqrt(max(A * A * h1 * h1 + K, 0.0))
    if K <= 0.0:
        return A * h1 - root
    return A * h1 + root


@njit(cache=True)
def _trapezoid(v0: float, v1: float, room: float, V: float, a: float, hold: float):
    """(peak, t_up, t_cruise, t_down, total time) of a trapezoid over `room` at acceleration
    a, cruising at least `hold` at a peak above both ends: vp^2 / a + hold vp <= room +
    (v0^2 + v1^2) / (2a). The peak is never below an end (a body the planned ends fit)."""
    c = room + (v0 * v0 + v1 * v1) / (2.0 * a)
    top = 0.5 * a * (-hold + math.sqrt(hold * hold + 4.0 * c / a))
    top = max(min(top, V), max(v0, v1))
    t_up = (top - v0) / a
    t_down = (top - v1) / a
    rest = room - (top * top - v0 * v0) / (2.0 * a) - (top * top - v1 * v1) / (2.0 * a)
    t_cruise = rest / top if (top > 0.0 and rest > 0.0) else 0.0
    return top, t_up, t_cruise, t_down, t_up + t_cruise + t_down


@njit(cache=True)
def body_profiles_filtered(
    v: np.ndarray,
    L: np.ndarray,
    V: np.ndarray,
    A: np.ndarray,
    hold_in: np.ndarray,
    hold_out: np.ndarray,
    T: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Peak speed, durations (speed-up, cruise, slow-down) and acceleration of each raw body:
    a trapezoid over the length its nodes' holds (`plan_speeds_filtered`) leave.

    A body between two nodes held on its side (alone in its windows, A from the axes' a_max)
    either cruises at least T at a peak above both ends (s'' keeps its sign within a window:
    |s_f'''| <= A / T), or runs at A / 2 without that cruise (|s_f'''| <= 2 (A / 2) / T), or
    at A where it takes at most T in all (a window then reaches into the holds on one side
    or the other, where s'' = 0, and never holds both signs: |s_f'''| <= A / T), whichever
    is quickest. A chain body's A already budgets s'' changing sign within a window
    (`plan_chains.chain_limits`): no cruise needed.
    """
    m = L.shape[0]
    vp = np.empty(m)
    t_up = np.empty(m)
    t_cruise = np.empty(m)
    t_down = np.empty(m)
    a_used = np.empty(m)
    for i in range(m):
        v0 = v[i]
        v1 = v[i + 1]
        a = A[i]
        room = L[i] - hold_out[i] * v0 - hold_in[i + 1] * v1
        alone = hold_out[i] > 0.0 and hold_in[i + 1] > 0.0
        best = _trapezoid(v0, v1, room, V[i], a, T if alone else 0.0)
        a_used[i] = a
        if alone and abs(v0 * v0 - v1 * v1) <= a * room:  # the ends fit at A / 2
            half = _trapezoid(v0, v1, room, V[i], 0.5 * a, 0.0)
            if half[4] < best[4]:
                best = half
                a_used[i] = 0.5 * a
        if alone:  # over at most T no window holds both signs of s'': at A, no cruise
            short = _trapezoid(v0, v1, room, V[i], a, 0.0)
            if short[4] <= T and short[4] < best[4]:
                best = short
                a_used[i] = a
        vp[i], t_up[i], t_cruise[i], t_down[i] = best[0], best[1], best[2], best[3]
    return vp, t_up, t_cruise, t_down, a_used


@njit(cache=True)
def erode(
    lo: np.ndarray,
    hi: np.ndarray,
    value: np.ndarray,
    reach: np.ndarray,
    group: np.ndarray,
    speed: np.ndarray,
    span: float,
) -> np.ndarray:
    """Each item's value lowered to that of any item of its group within that item's reach
    (value (n,) or (n, k): each column alike, in one pass).

    Items are intervals [lo, hi] along s in order; item j reaches item i when the gap between
    them is at most reach[j], or at most `span` times the highest speed of the items from i to
    j (the distance a window of `span` [s] can cover between them). Items of group -1 are left
    alone and reach nothing.
    """
    n = lo.shape[0]
    source = np.ascontiguousarray(value).reshape(n, -1)
    out = source.copy()
    columns = out.shape[1]
    # No item reaches further than its run of one group's largest reach or span x speed.
    far_of = np.zeros(n)
    start = 0
    for k in range(1, n + 1):
        if k == n or group[k] != group[start]:
            far = 0.0
            for q in range(start, k):
                far = max(far, reach[q], span * speed[q])
            far_of[start:k] = far
            start = k
    for i in range(n):
        if group[i] < 0:
            continue
        far = far_of[i]
        for step in (1, -1):
            j = i + step
            top = speed[i]
            while 0 <= j < n and group[j] == group[i]:
                gap = lo[j] - hi[i] if step > 0 else lo[i] - hi[j]
                if gap > far:
                    break
                top = max(top, speed[j])
                if gap <= max(reach[j], span * top):
                    for c in range(columns):
                        out[i, c] = min(out[i, c], source[j, c])
                j += step
    return out.reshape(value.shape)


@njit(cache=True)
def _piece_state(
    kind: int, s0: float, v0: float, vp: float, A: float, t_up: float, t_cruise: float, tau: float
):
    """(s, ds/dt, integral of s from the piece's start) at tau >= 0 into a raw piece: a hold,
    a cruise, or a trapezoid body (up at +A, cruise at vp, down at -A)."""
    if kind == HOLD:
        return s0, 0.0, s0 * tau
    if kind == CRUISE:
        return s0 + v0 * tau, v0, s0 * tau + 0.5 * v0 * tau * tau
    s = s0
    v = v0
    G = 0.0
    dt = min(tau, t_up)
    G += s * dt + 0.5 * v * dt * dt + A * dt**3 / 6.0
    s += v * dt + 0.5 * A * dt * dt
    v += A * dt
    rest = tau - dt
    if rest > 0.0:
        dt = min(rest, t_cruise)
        G += s * dt + 0.5 * v * dt * dt
        s += v * dt
        rest -= dt
    if rest > 0.0:
        dt = min(rest, max(v / A, 0.0))
        G += s * dt + 0.5 * v * dt * dt - A * dt**3 / 6.0
        s += v * dt - 0.5 * A * dt * dt
        v -= A * dt
        rest -= dt
        G += s * rest
    return s, max(v, 0.0), G


Real = TypeVar("Real", float, np.ndarray)


@njit(cache=True)
def two_sum(a: Real, b: Real) -> tuple[Real, Real]:
    """(a + b rounded, its rounding error): Knuth's error-free sum, elementwise on arrays too."""
    total = a + b
    b_part = total - a
    return total, (a - (total - b_part)) + (b - b_part)


@njit(cache=True)
def raw_samples(
    times: np.ndarray,
    kind: np.ndarray,
    t0: np.ndarray,
    dur: np.ndarray,
    s0: np.ndarray,
    v0: np.ndarray,
    vp: np.ndarray,
    A: np.ndarray,
    t_up: np.ndarray,
    t_cruise: np.ndarray,
    F0: float,
    F0_lo: float,
):
    """s, ds/dt, F = F0 + integral of s from t0[0] (as F + F_lo), and the piece, at increasing
    sample times of raw (trapezoid) pieces; F at the end of the last piece is returned too.

    F grows with time (s times t: hundreds of m s on a program of minutes) while the filter
    needs F(t) - F(t - T), the integral over one window: a double alone loses eps |F| / T of
    s_f there, which the samples' third differences multiply by 8 / period^3 (1.4e-4 of the
    jerk limit at T = 9 ms after 170 s). F is therefore carried as a sum of two doubles (the
    pieces' integrals added with their rounding errors, `two_sum`), and F(t) and F(t - T),
    close to each other, subtract exactly in their high parts.
    """
    m = t0.shape[0]
    F_start = np.empty(m + 1)
    F_start_lo = np.empty(m + 1)
    F_start[0] = F0
    F_start_lo[0] = F0_lo
    for p in range(m):
        _, _, G = _piece_state(kind[p], s0[p], v0[p], vp[p], A[p], t_up[p], t_cruise[p], dur[p])
        hi, err = two_sum(F_start[p], G)
        F_start[p + 1], F_start_lo[p + 1] = two_sum(hi, err + F_start_lo[p])
    n = times.shape[0]
    s = np.empty(n)
    sd = np.empty(n)
    F = np.empty(n)
    F_lo = np.empty(n)
    piece = piece_of_samples(times, t0, dur)
    for k in range(n):
        p = int(piece[k])
        tau = times[k] - t0[p]
        if tau < 0.0:  # a rounding error before the first piece: at its start point
            s[k], sd[k] = s0[p], 0.0
            G = s0[p] * tau
        else:
            s[k], sd[k], G = _piece_state(
                kind[p], s0[p], v0[p], vp[p], A[p], t_up[p], t_cruise[p], tau
            )
        hi, err = two_sum(F_start[p], G)
        F[k], F_lo[k] = two_sum(hi, err + F_start_lo[p])
    return s, sd, F, F_lo, piece, F_start[m], F_start_lo[m]


def window_integral(
    dF: np.ndarray, dF_lo: np.ndarray, s_then: np.ndarray, dt: np.ndarray, span: float
) -> np.ndarray:
    """The integral of s over the `span` before each sample from F's differences over the
    sample times' differences `dt` (both parts of F's, `raw_samples`). A sample time k * period
    is rounded to eps t (1.5e-14 s at 137 s), and over that much more or less time F gains s
    times it: with the path coordinate s at metres, 1e-11 m in s_f at T = 9 ms. So the window's
    start is moved to exactly `span` before its end with the speed-free part s_then of s,
    leaving (s - s_then) times the rounding: the speed times T times eps t."""
    return (dF + dF_lo) - s_then * (dt - span)


# Columns of the raw sample rows `box_filter` averages (the planner's filter history too).
ROW_S, ROW_SD, ROW_F, ROW_T, ROW_F_LO = range(5)


def box_filter(history: np.ndarray, raw: np.ndarray, span: float) -> np.ndarray:
    """The raw samples (rows s, ds/dt, F, t, F_lo: `ROW_*`) averaged over the last `span` [s]:
    s_f, ds_f/dt and d2s_f/dt2 at each row of `raw`, `history` holding the n - 1 rows before it
    (n - 1 = span / period). Exact: s_f = (F(t) - F(t - span)) / span and so on."""
    lag = len(history)
    joined = np.concatenate((history, raw))
    now, then = joined[lag:], joined[: len(joined) - lag]
    window = window_integral(
        now[:, ROW_F] - then[:, ROW_F],
        now[:, ROW_F_LO] - then[:, ROW_F_LO],
        then[:, ROW_S],
        now[:, ROW_T] - then[:, ROW_T],
        span,
    )
    # The mean lies between the window's ends: held there, the rounding of F cannot carry it
    # past a stop (onto the next move) before it comes to rest, and at rest it is exact.
    s = np.clip(window / span, then[:, ROW_S], now[:, ROW_S])
    return np.column_stack(
        (
            s,
            (now[:, ROW_S] - then[:, ROW_S]) / span,
            (now[:, ROW_SD] - then[:, ROW_SD]) / span,
        )
    )
