# pyright: reportConstantRedefinition=false
# (U, A are the field's symbols for a speed bound and an acceleration, not constants)
"""Planner stage 4a (jerk profile): the chains' accelerations at the speeds the plan reaches.

Before the speeds are known, `plan_chains.chain_limits` gives each chain body the
acceleration of s'' that its curvature terms leave at the body's speed cap, and
`plan_chains._eroded` spreads the lowest of them over T times the highest cap between
(a filtered acceleration at s averages raw ones from that far). Both are bounds for any speed
the plan may reach. Near a sharp corner they are far too low: the chain's last blend, squeezed
by the corner, has a large curvature, which at its cap leaves s'' almost nothing, and that
nothing is spread over T v_cap (3.3 mm at 66.7 mm/s) of the approach, which the plan runs at
a few mm/s. A raster's row end decelerated at 0.4-0.9 m/s^2 for it.

Here the terms are evaluated at the speeds of a plan instead: each body's A at the highest
raw speed within a window's reach of it (the filtered speed there is a mean of those), and
eroded over T times the highest raw speed between (the distance a window covers). A higher A
makes the plan faster, so the bound is a fixed point: the speeds assumed (U) start at the
first plan's, and a plan is taken only when its own raw speeds stay within U; else U grows to
them and the limits are computed again, up to RELAX_STEPS times (then the first plan stays).
The curvature terms fall with the speed (v^2, v^3), so every A found is at least the cap's.

In a window that is not the last, the bodies from the commit node on keep their caps as U: the
next window plans them again, maybe faster, and the committed bodies' A must hold for that.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.jerk_filter import erode
from feed_twin.gcode.plan_chains import Bodies, chain_acceleration
from feed_twin.gcode.plan_limits import AxisLimits
from feed_twin.gcode.plan_profile import SpeedProfile, speed_profile

RELAX_STEPS = 4  # plans tried, each with what the one before did assumed
SPEED_SLACK = 1e-9  # relative: a plan this much above the speeds assumed still fits (rounding)


class _Assumed(NamedTuple):
    """What a trial's limits assume of its plan, per body."""

    U: np.ndarray  # [m/s] the highest raw speed on each body
    one_sign: np.ndarray  # the raw s'' keeps one sign over every window that reaches it


def relaxed_plan(
    bodies: Bodies,
    speeds: SpeedProfile,
    limits: AxisLimits,
    *,
    v_first: float,
    fixed_from: int,
) -> tuple[Bodies, SpeedProfile]:
    """The bodies with their chains' A at what their plan does, and that plan; the given
    ones where no plan within RELAX_STEPS keeps to what it assumed. Bodies from `fixed_from`
    on, and those of the chain the window starts in (unless the first node's holds part it
    from the committed motion), keep their limits: later windows plan them again."""
    relax = bodies.relax
    if relax is None or not np.any(relax.group >= 0):
        return bodies, speeds
    group = relax.group
    fixed = np.zeros(len(group), dtype=bool)
    fixed[fixed_from:] = True
    if not bodies.extended[0] and group[0] >= 0:
        fixed |= group == group[0]
    if np.all(fixed | (group < 0)):
        return bodies, speeds
    cap = np.where(np.isfinite(relax.V), relax.V, 0.0)
    assumed = _assumed(bodies, speeds, limits, cap, fixed)
    for _ in range(RELAX_STEPS):
        trial = _with_assumed(bodies, limits, assumed, fixed)
        planned = speed_profile(trial, v_first=v_first, window_s=limits.window_s)
        found = _assumed(bodies, planned, limits, cap, fixed)
        slower = found.U <= assumed.U * (1.0 + SPEED_SLACK)
        if np.all(slower) and np.all(found.one_sign | ~assumed.one_sign):
            return trial, planned
        assumed = _Assumed(
            U=np.maximum(assumed.U, found.U), one_sign=assumed.one_sign & found.one_sign
        )
    return bodies, speeds


def _assumed(
    bodies: Bodies, speeds: SpeedProfile, limits: AxisLimits, cap: np.ndarray, fixed: np.ndarray
) -> _Assumed:
    """What a plan does on each body: its highest raw speed (the cap where fixed), and whether
    the raw s'' keeps one sign over the bodies a window at it reaches (T times the highest
    speed between; a fixed body's sign is unknown: both)."""
    relax = bodies.relax
    assert relax is not None
    U = np.maximum(np.maximum(speeds.v[:-1], speeds.v[1:]), speeds.vp)
    U = np.where(fixed, cap, U)
    rises = (speeds.t_up > 0.0) | fixed
    falls = (speeds.t_down > 0.0) | fixed
    none = np.zeros(len(U))
    T = limits.window_s
    rise_near = erode(relax.lo, relax.hi, -rises.astype(float), none, relax.group, U, T) < 0.0
    fall_near = erode(relax.lo, relax.hi, -falls.astype(float), none, relax.group, U, T) < 0.0
    return _Assumed(U=U, one_sign=~(rise_near & fall_near))


def _with_assumed(
    bodies: Bodies, limits: AxisLimits, assumed: _Assumed, fixed: np.ndarray
) -> Bodies:
    """The chain bodies' A from their curvature terms at the highest raw speed within a
    window's reach, with s''' of one sign where the plan keeps it, eroded over T times the
    highest speed between; the fixed bodies keep theirs."""
    relax = bodies.relax
    assert relax is not None
    T = limits.window_s
    U = assumed.U
    none = np.zeros(len(U))
    reached = -erode(relax.lo, relax.hi, -U, none, relax.group, U, T)
    A = chain_acceleration(
        relax.terms, np.minimum(relax.V, reached), limits, one_sign=assumed.one_sign
    )
    A = erode(relax.lo, relax.hi, np.where(fixed, bodies.A, A), none, relax.group, U, T)
    return dataclasses.replace(bodies, A=np.where((relax.group >= 0) & ~fixed, A, bodies.A))
