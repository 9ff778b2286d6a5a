# pyright: reportConstantRedefinition=false
# (G, J, A are the field's symbols for an integral, a jerk and an acceleration, not constants)
"""One-dimensional feed profiles along the path, and the blended path geometry (numba kernels).

The planner moves a path parameter s [m] (arc length of the programmed polyline) with a
profile made of pieces:

- body: speed changes v0 -> vp -> v1 at acceleration A with a cruise at vp between
  (trapezoid: a change of dv takes dv/A and covers (v_from + v_to)/2 * dv/A). The jerk
  profile filters such a plan (`jerk_filter`); S-curves per body are gone.
- cruise: constant speed through a corner blend (ds/dt = v, d2s/dt2 = 0).
- hold: standstill (dwell, pauses).

Corner blend (G64) at a corner P_c between unit directions u_A and u_B, dU = u_B - u_A, over
sigma = s - s_c in [-w, w]:
    x(s) = P_c + u_A*sigma + dU*G(sigma),  dx/ds = u_A + dU*h,  d2x/ds2 = dU*h'
with h' a triangle (0 -> 1/w -> 0), so h runs 0 -> 1 and G(w) = w (the blend rejoins the
second line exactly). The largest distance from the corner is |dU|*w/6. Along a cruise piece
the axis acceleration is dU_i * h' * v^2 <= |dU_i| v^2 / w and the jerk is |dU_i| v^3 / w^2,
which is how the planner sizes w and the corner speed. Blends of neighbouring corners may
overlap (chains): on a move they simply add, x(s) = P0 + u*sigma + dU_start*(G - sigma) +
dU_end*G, and the sum stays within the larger of the two deviations, because each term is
convex and vanishes at the other end. In general a = x'(s) s'' + x''(s) s'^2, which
`evaluate_path` evaluates. Acceleration is continuous everywhere.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

BODY = 0
CRUISE = 1
HOLD = 2


@njit(cache=True)
def phase_time(dv: float, A: float) -> float:
    """Duration [s] of a speed change of dv >= 0 at acceleration A."""
    if dv <= 0.0:
        return 0.0
    return dv / A


@njit(cache=True)
def phase_distance(va: float, vb: float, A: float) -> float:
    return 0.5 * (va + vb) * phase_time(abs(vb - va), A)


@njit(cache=True)
def reach(v_known: float, L: float, A: float, v_cap: float) -> float:
    """Largest v <= v_cap from which one speed change to v_known fits in the length L
    (either way): x = v - v_known solves x^2 + 2 v_k x - 2AL = 0."""
    if v_cap <= v_known:
        return v_cap
    if L <= 0.0:
        return v_known
    if phase_distance(v_cap, v_known, A) <= L:
        return v_cap
    x = 2.0 * A * L / (v_known + math.sqrt(v_known * v_known + 2.0 * A * L))
    v = min(v_known + x, v_cap)
    # v - v_known loses digits when x << v_known, so the distance can come out slightly above
    # L; step down (by growing relative amounts) until it fits, keeping the result feasible.
    shrink = 1e-15
    for _ in range(40):
        if phase_distance(v, v_known, A) <= L:
            return v
        v = v_known + (v - v_known) * (1.0 - shrink)
        shrink *= 4.0
    return v_known


@njit(cache=True)
def plan_speeds(cap: np.ndarray, L: np.ndarray, A: np.ndarray, v_first: float) -> np.ndarray:
    """Boundary speeds: backward (braking bounds) then forward pass over bodies i (node i ->
    node i+1). The forward pass takes the bound when slowing down, so it always fits."""
    m = L.shape[0]
    v = cap.copy()
    v[0] = v_first
    for i in range(m - 1, 0, -1):
        v[i] = min(v[i], reach(v[i + 1], L[i], A[i], v[i]))
    for i in range(m):
        v[i + 1] = min(v[i + 1], reach(v[i], L[i], A[i], v[i + 1]))
    return v


@njit(cache=True)
def body_profiles(
    v: np.ndarray, L: np.ndarray, V: np.ndarray, A: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Peak speed vp and durations (speed-up, cruise, slow-down) of each body."""
    m = L.shape[0]
    vp = np.empty(m)
    t_up = np.empty(m)
    t_cruise = np.empty(m)
    t_down = np.empty(m)
    for i in range(m):
        v0 = v[i]
        v1 = v[i + 1]
        a = A[i]
        top = V[i]
        if phase_distance(v0, top, a) + phase_distance(top, v1, a) > L[i]:
            lo = max(v0, v1)
            hi = top
            for _ in range(48):
                mid = 0.5 * (lo + hi)
                if mid <= lo or mid >= hi:
                    break
                if phase_distance(v0, mid, a) + phase_distance(mid, v1, a) <= L[i]:
                    lo = mid
                else:
                    hi = mid
            top = lo
        vp[i] = top
        t_up[i] = phase_time(top - v0, a)
        t_down[i] = phase_time(top - v1, a)
        rest = L[i] - phase_distance(v0, top, a) - phase_distance(top, v1, a)
        t_cruise[i] = rest / top if (top > 0.0 and rest > 0.0) else 0.0
    return vp, t_up, t_cruise, t_down


@njit(cache=True)
def _phase_eval(va: float, vb: float, A: float, tau: float):
    """(s, v, a) at time tau into a speed change va -> vb; s counted from its start."""
    dv = vb - va
    if dv == 0.0:
        return va * tau, va, 0.0
    sg = 1.0 if dv > 0.0 else -1.0
    T = abs(dv) / A
    tau = min(max(tau, 0.0), T)
    return va * tau + 0.5 * sg * A * tau * tau, va + sg * A * tau, sg * A


@njit(cache=True)
def piece_of_samples(times: np.ndarray, t0: np.ndarray, dur: np.ndarray) -> np.ndarray:
    """Index of the piece (starts t0, durations dur, in time order) running at each of the
    increasing sample times; the last piece runs on past its end."""
    n = times.shape[0]
    m = t0.shape[0]
    piece = np.empty(n, dtype=np.int64)
    p = 0
    for k in range(n):
        while p < m - 1 and times[k] >= t0[p] + dur[p]:
            p += 1
        piece[k] = p
    return piece


@njit(cache=True)
def sample_pieces(
    times: np.ndarray,
    kind: np.ndarray,
    t0: np.ndarray,
    dur: np.ndarray,
    s0: np.ndarray,
    v0: np.ndarray,
    vp: np.ndarray,
    v1: np.ndarray,
    A: np.ndarray,
    t_up: np.ndarray,
    t_cruise: np.ndarray,
):
    """Path parameter s, ds/dt, d2s/dt2 and the active piece at increasing sample times."""
    n = times.shape[0]
    s = np.empty(n)
    sd = np.empty(n)
    sdd = np.empty(n)
    piece = piece_of_samples(times, t0, dur)
    for k in range(n):
        p = int(piece[k])
        tau = min(max(times[k] - t0[p], 0.0), dur[p])
        if kind[p] == HOLD:
            s[k] = s0[p]
            sd[k] = 0.0
            sdd[k] = 0.0
        elif kind[p] == CRUISE:
            s[k] = s0[p] + v0[p] * tau
            sd[k] = v0[p]
            sdd[k] = 0.0
        else:
            if tau < t_up[p]:
                ds, vv, aa = _phase_eval(v0[p], vp[p], A[p], tau)
            elif tau < t_up[p] + t_cruise[p]:
                d_up = 0.5 * (v0[p] + vp[p]) * t_up[p]
                ds, vv, aa = d_up + vp[p] * (tau - t_up[p]), vp[p], 0.0
            else:
                d_up = 0.5 * (v0[p] + vp[p]) * t_up[p]
                ds, vv, aa = _phase_eval(vp[p], v1[p], A[p], tau - t_up[p] - t_cruise[p])
                ds += d_up + vp[p] * t_cruise[p]
            s[k] = s0[p] + ds
            sd[k] = vv
            sdd[k] = aa
    return s, sd, sdd, piece


@njit(cache=True)
def _blend_shape(sigma: float, w: float):
    """G, h, h' of the corner blend at sigma in [-w, w] (see the module docstring)."""
    if sigma <= 0.0:
        q = sigma + w
        return q**3 / (6.0 * w * w), q * q / (2.0 * w * w), q / (w * w)
    q = w - sigma
    return sigma + q**3 / (6.0 * w * w), 1.0 - q * q / (2.0 * w * w), q / (w * w)


@njit(cache=True)
def evaluate_path(
    s: np.ndarray,
    sd: np.ndarray,
    sdd: np.ndarray,
    S0: np.ndarray,
    L: np.ndarray,
    P0: np.ndarray,
    P1: np.ndarray,
    u: np.ndarray,
    w_start: np.ndarray,
    du_start: np.ndarray,
    w_end: np.ndarray,
    du_end: np.ndarray,
    first_seg: np.ndarray,
):
    """Axis position, velocity and acceleration at path parameters s (non-decreasing).

    `first_seg[k]` is the first move that sample k may lie on (from its profile piece).
    """
    n = s.shape[0]
    m = S0.shape[0]
    na = P0.shape[1]
    pos = np.empty((n, na))
    vel = np.empty((n, na))
    acc = np.empty((n, na))
    seg = np.empty(n, dtype=np.int64)
    k = 0
    for idx in range(n):
        si = s[idx]
        # At a stop both moves touch s; the piece knows which move it runs on.
        k = max(k, first_seg[idx])
        while k < m - 1 and si > S0[k] + L[k]:
            k += 1
        seg[idx] = k
        sigma = si - S0[k]
        v = sd[idx]
        a = sdd[idx]
        for i in range(na):
            pos[idx, i] = P0[k, i] + u[k, i] * sigma
            vel[idx, i] = u[k, i]
            acc[idx, i] = 0.0
        # Blends of the node at each end of the move; they may overlap and simply add up.
        if w_start[k] > 0.0 and sigma < w_start[k]:
            sg = max(sigma, 0.0)
            G, h, hp = _blend_shape(sg, w_start[k])
            for i in range(na):
                pos[idx, i] += du_start[k, i] * (G - sg)
                vel[idx, i] += du_start[k, i] * (h - 1.0)
                acc[idx, i] += du_start[k, i] * hp
        if w_end[k] > 0.0 and L[k] - sigma < w_end[k]:
            sg = max(sigma - L[k], -w_end[k])
            G, h, hp = _blend_shape(sg, w_end[k])
            for i in range(na):
                pos[idx, i] += du_end[k, i] * G
                vel[idx, i] += du_end[k, i] * h
                acc[idx, i] += du_end[k, i] * hp
        for i in range(na):
            d = vel[idx, i]
            vel[idx, i] = d * v
            acc[idx, i] = d * a + acc[idx, i] * v * v
    return pos, vel, acc, seg
