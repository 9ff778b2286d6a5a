# pyright: reportConstantRedefinition=false
# (U, A, V are the field's symbols for speeds and an acceleration, not constants)
"""Planner stage 4a (jerk profile): the chains' limits at what the plan does.

Before the speeds are known, `plan_chains` bounds each chain body for any speed the plan may
reach: its speed cap is lowered to that of every blend within T V / 2 (a filtered speed is a
mean of raw ones), its acceleration A of s'' is what its curvature terms leave at the cap
with |s'''| <= 2 A / T (the raw s'' may change sign within a window), spread over T times the
highest cap between. Where a chain ends at a sharp corner those bounds are far too low: a
raster's row end held 55.75 instead of 66.7 mm/s over its last 2 mm (the squeezed last
blend's cap, eroded) and braked at A = 1.2-1.5 m/s^2, at speeds the plan never reaches there
(T = 50 ms, the default jerk limit then; at T = 9 ms the erosion spans 0.3 mm).

Here they come from a plan instead:
- each body's A from its curvature terms at the highest raw speed within a window's reach
  (the filtered speed there is a mean of those), with |s'''| <= A / T where the raw s'' keeps
  one sign over every body a window at it reaches, eroded over T times the highest raw speed
  between (the distance a window covers);
- each body's speed cap lowered to its neighbours' within T U / 2 of the raw speed U the
  plan runs there, and the plan's filtered speed checked on the samples of its raw plan
  against every chain body's own cap: a chain where it is not met keeps the caps' erosion.
A faster plan reaches further and meets other signs, so these are a fixed point: what the
plan does is assumed from the first (bounded) plan, a plan is taken only when it keeps to
what it assumed, else the assumptions grow to what it did and the limits are computed again,
up to RELAX_STEPS times (then the bounded plan stays). Every limit found is at least the
bound's.

The chains the committed motion's windows still reach, those from the commit node on and
the one that spans it keep their bounds: later windows plan them again, maybe faster, and
what is committed must hold for that.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.jerk_filter import erode, raw_samples, window_integral
from feed_twin.gcode.plan_chains import Bodies, ChainRelax, ChainTerms, chain_acceleration
from feed_twin.gcode.plan_limits import AxisLimits
from feed_twin.gcode.plan_profile import (
    BODY_SLOT,
    CRUISE_SLOT,
    PIECES_PER_NODE,
    Pieces,
    SpeedProfile,
    motion_pieces,
    speed_profile,
)
from feed_twin.gcode.plan_sampling import piece_starts

RELAX_STEPS = 4  # plans tried, each with what the one before did assumed
SPEED_SLACK = 1e-9  # relative: a plan this much above what it assumed still fits (rounding)
RISES, FALLS = 1, 2  # bits: the raw s'' of a body is positive, negative somewhere


class _Assumed(NamedTuple):
    """What a trial's limits assume of its plan, per body."""

    U: np.ndarray  # [m/s] the highest raw speed on each body
    one_sign: np.ndarray  # the raw s'' keeps one sign over every window that reaches it
    strict: np.ndarray  # the speed cap eroded as for any speed (over T V / 2)
    reached: np.ndarray  # [m/s] the highest U within a window's reach of each body


def relaxed_plan(
    bodies: Bodies,
    speeds: SpeedProfile,
    limits: AxisLimits,
    *,
    v_first: float,
    fixed_from: int,
) -> tuple[Bodies, SpeedProfile]:
    """The bodies with their chains' limits at what their plan does, and that plan; the given
    ones where no plan within RELAX_STEPS keeps to what it assumed. Bodies from `fixed_from`
    (the commit node) on, those of the chain that spans it and those of the chain the window
    starts in (unless the first node's holds part it from the committed motion) keep theirs."""
    relax = bodies.relax
    if relax is None or not np.any(relax.group >= 0):
        return bodies, speeds
    group = relax.group
    fixed = np.zeros(len(group), dtype=bool)
    fixed[fixed_from:] = True
    if not bodies.extended[0] and group[0] >= 0:
        fixed |= group == group[0]
    if fixed_from < len(group) and group[fixed_from] >= 0:
        fixed |= group == group[fixed_from]
    if np.all(fixed | (group < 0)):
        return bodies, speeds
    # The chains from the one spanning the commit node on are fixed and reach no other:
    # the erosions run over the bodies before them alone.
    live = fixed_from
    if fixed_from < len(group) and group[fixed_from] >= 0:
        live = int(np.flatnonzero(group == group[fixed_from])[0])
    relax = relax._replace(lo=relax.lo[:live], hi=relax.hi[:live], group=group[:live])
    cap = np.where(np.isfinite(relax.V), relax.V, 0.0)
    assumed = _assumed(relax, speeds, limits, cap, fixed)
    for _ in range(RELAX_STEPS):
        trial = _with_assumed(bodies, relax, limits, assumed, fixed)
        planned = speed_profile(trial, v_first=v_first, window_s=limits.window_s)
        found = _assumed(relax, planned, limits, cap, fixed)
        raised = trial.V > bodies.V * (1.0 + SPEED_SLACK)
        over = (
            _over_cap(
                trial, planned, limits, v_first=v_first, fixed_from=fixed_from, fixed=fixed,
                raised=raised,
            )
            if np.any(raised)
            else raised
        )  # fmt: skip
        slower = found.U <= assumed.U * (1.0 + SPEED_SLACK)
        signs = found.one_sign | ~assumed.one_sign
        if np.all(slower) and np.all(signs) and not np.any(over):
            return trial, planned
        U = np.maximum(assumed.U, found.U)
        _, reached = _window_reach(relax, U, limits.window_s, np.zeros(len(U), dtype=np.int64))
        assumed = _Assumed(
            U=U,
            one_sign=assumed.one_sign & found.one_sign,
            strict=assumed.strict | over,
            reached=reached,
        )
    return bodies, speeds


def _assumed(
    relax: ChainRelax,
    speeds: SpeedProfile,
    limits: AxisLimits,
    cap: np.ndarray,
    fixed: np.ndarray,
) -> _Assumed:
    """What a plan does on each body: its highest raw speed (the cap where fixed), and whether
    the raw s'' keeps one sign over the bodies a window at it reaches (T times the highest
    speed between; a fixed body's sign is unknown: both)."""
    U = np.maximum(np.maximum(speeds.v[:-1], speeds.v[1:]), speeds.vp)
    U = np.where(fixed, cap, U)
    bits = np.where((speeds.t_up > 0.0) | fixed, RISES, 0)
    bits |= np.where((speeds.t_down > 0.0) | fixed, FALLS, 0)
    near, reached = _window_reach(relax, U, limits.window_s, bits)
    both = RISES | FALLS
    return _Assumed(U=U, one_sign=(near & both) != both, strict=fixed, reached=reached)


def _with_assumed(
    bodies: Bodies, live_relax: ChainRelax, limits: AxisLimits, assumed: _Assumed, fixed: np.ndarray
) -> Bodies:
    """The chain bodies' speed caps eroded over T U / 2 (T V / 2 where strict), their A from
    their curvature terms at the highest raw speed within a window's reach, with s''' of one
    sign where the plan keeps it, eroded over T times the highest speed between; the fixed
    bodies keep theirs, and the nodes' caps follow the bodies'."""
    relax = live_relax
    T = limits.window_s
    U = assumed.U
    none = np.zeros(len(U))
    chain = np.zeros(len(U), dtype=bool)
    chain[: len(relax.group)] = relax.group >= 0
    chain &= ~fixed
    V_far = np.where(np.isfinite(relax.V), relax.V, 0.0)
    reach = np.where(assumed.strict, 0.5 * T * V_far, 0.0)
    V = _eroded_live(relax, np.where(fixed, bodies.V, relax.V), reach, none, 0.0)
    V = np.where(chain, V, bodies.V)
    idx = np.flatnonzero(chain)
    A = bodies.A.copy()
    A[idx] = chain_acceleration(
        ChainTerms(*(term[idx] for term in relax.terms)),
        np.minimum(relax.V[idx], assumed.reached[idx]),
        limits,
        one_sign=assumed.one_sign[idx],
    )
    A = _eroded_live(relax, A, none, U, T)
    assert bodies.relax is not None
    in_chain = bodies.relax.group >= 0
    node_cap = relax.node_cap.copy()
    node_cap[1:] = np.where(in_chain, np.minimum(node_cap[1:], V), node_cap[1:])
    node_cap[:-1] = np.where(in_chain, np.minimum(node_cap[:-1], V), node_cap[:-1])
    return dataclasses.replace(bodies, V=V, A=np.where(chain, A, bodies.A), cap=node_cap)


def _over_cap(
    bodies: Bodies,
    speeds: SpeedProfile,
    limits: AxisLimits,
    *,
    v_first: float,
    fixed_from: int,
    fixed: np.ndarray,
    raised: np.ndarray,
) -> np.ndarray:
    """Chain bodies (not fixed) where the filtered plan runs above their own speed cap, from
    the raw plan up to `fixed_from` (before it: v_first) filtered at every period from where
    a `raised` body's raw motion starts to a window after it ends (elsewhere the caps are
    eroded as for any speed)."""
    relax = bodies.relax
    assert relax is not None
    n_moves = len(bodies.S) - 1
    pieces = motion_pieces(bodies, speeds, q_commit=fixed_from, n_moves=n_moves)
    t0, t_end = piece_starts(pieces, 0.0)
    period, T = limits.period_s, limits.window_s
    # Body q's raw motion: from its node's cruise to the next node's cruise end.
    q = np.flatnonzero(raised[:fixed_from])
    first = t0[PIECES_PER_NODE * q + CRUISE_SLOT]
    after = PIECES_PER_NODE * (q + 1) + BODY_SLOT
    last = np.where(after < len(t0), t0[np.minimum(after, len(t0) - 1)], t_end) + T
    k_all = np.arange(
        math.floor(float(np.min(first)) / period) - 1, math.ceil(float(np.max(last)) / period) + 2
    )
    t_all = k_all * period
    # On the grid within any of the intervals [first, last] (padded by a period).
    started = np.searchsorted(np.sort(first), t_all + period, side="right")
    ended = np.searchsorted(np.sort(last), t_all - period, side="left")
    times = t_all[started > ended]
    s_f, v_f, a_f = _filtered(pieces, t0, times, v_first, T)
    # The highest filtered speed between two samples: above the higher of them only at a
    # maximum between them, by at most |s_f'''| period^2 / 8 (|s_f'''| <= 2 max_i a_max_i / T).
    bulge = 0.25 * float(np.max(limits.a_max)) / T * period**2
    peak = (a_f[:-1] > 0.0) & (a_f[1:] < 0.0)
    v_hi = np.maximum(v_f[:-1], v_f[1:]) + np.where(peak, bulge, 0.0)
    body = np.clip(np.searchsorted(relax.lo, s_f, side="right") - 1, 0, len(relax.lo) - 1)
    on = (s_f >= relax.lo[body]) & (s_f <= relax.hi[body]) & (relax.group[body] >= 0)
    on &= ~fixed[body]
    cap = np.where(on, relax.V[body], np.inf)
    fast = v_hi > np.minimum(cap[:-1], cap[1:]) * (1.0 + SPEED_SLACK)
    fast &= np.diff(times) < 1.5 * period  # neighbours on the grid
    over = np.zeros(len(relax.lo), dtype=bool)
    over[body[:-1][fast & on[:-1]]] = True
    over[body[1:][fast & on[1:]]] = True
    return over


def _filtered(
    pieces: Pieces, t0: np.ndarray, times: np.ndarray, v_first: float, T: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Filtered s, ds/dt and d2s/dt2 of the raw pieces (starting at t = 0, at v_first before)
    at the increasing `times`: (F(t) - F(t - T)) / T and so on (`jerk_filter.box_filter`)."""
    p = pieces

    def raw(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s, sd, F, F_lo, _, _, _ = raw_samples(
            t, p.kind, t0, p.dur, p.s0, p.v0, p.vp, p.A, p.t_up, p.t_cruise, 0.0, 0.0
        )
        before = t < 0.0
        s0 = float(p.s0[0])
        s = np.where(before, s0 + v_first * t, s)
        sd = np.where(before, v_first, sd)
        F = np.where(before, s0 * t + 0.5 * v_first * t * t, F)
        F_lo = np.where(before, 0.0, F_lo)
        return s, sd, F, F_lo

    t_then = times - T
    s1, sd1, F1, F1_lo = raw(times)
    s0, sd0, F0, F0_lo = raw(t_then)
    window = window_integral(F1 - F0, F1_lo - F0_lo, s0, times - t_then, T)
    s_f = np.clip(window / T, s0, s1)
    return s_f, (s1 - s0) / T, (sd1 - sd0) / T


def _window_reach(
    relax: ChainRelax, U: np.ndarray, span: float, bits: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(the bits of any body, the highest U of any body) of its chain within a window's reach
    of each body: the gap between them at most `span` times the highest U between."""
    columns = -np.column_stack((bits & RISES, bits & FALLS, U)).astype(float)
    near = -_eroded_live(relax, columns, np.zeros(len(U)), U, span)
    return np.where(near[:, 0] > 0.0, RISES, 0) | np.where(near[:, 1] > 0.0, FALLS, 0), near[:, 2]


def _eroded_live(
    relax: ChainRelax, value: np.ndarray, reach: np.ndarray, speed: np.ndarray, span: float
) -> np.ndarray:
    """`jerk_filter.erode` over the bodies `relax` lists (lo, hi, group: the live ones), the
    rest of `value` as it is."""
    live = len(relax.group)
    out = value.copy()
    out[:live] = erode(
        relax.lo, relax.hi, value[:live], reach[:live], relax.group, speed[:live], span
    )
    return out
