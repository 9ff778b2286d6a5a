# pyright: reportConstantRedefinition=false
# (G, J, A are the field's symbols for an integral, a jerk and an acceleration, not constants)
"""Planner stage 1, move limits: each straight move's length, direction and the speed,
acceleration and jerk along it that keep every axis within its own limits.

For a move with unit direction u (machine coordinates, all axes) the axis components are
u_i * (ds/dt, d2s/dt2, d3s/dt3), so

    V = min(F, min_i v_max_i/|u_i|)     (G0: min_i rapid_i/|u_i|)
    A = min_i a_max_i/|u_i|,   J = min_i j_max_i/|u_i|

An axis that does not move (u_i = 0) sets no limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feed_twin.gcode.config import NcConfig

FILTER_ROUNDING = 1e-4  # share of a_max, j_max the jerk profile leaves for rounding and sampling
# A step of curvature K [1/m] over a stretch shorter than a sample's travel is seen by the
# sampled positions' third differences (a quadratic B-spline of 3 periods, peak 3 / (4 period))
# as at most KICK_WEIGHT * K v^2 / period per step (two steps per move counted: 3/4 each).
KICK_WEIGHT = 1.5
CUBIC_NEWTON_STEPS = 12  # Newton steps for a speed cap under j v^3 + c v^2 (converged)


@dataclass(frozen=True, kw_only=True)
class AxisLimits:
    """Per-axis limits of the configured machine (arrays over the axes, SI)."""

    v_max: np.ndarray  # [m/s or rad/s] feed-move speed limit per axis
    rapid: np.ndarray  # [m/s or rad/s] G0 speed per axis
    a_max: np.ndarray  # [m/s^2 or rad/s^2]
    j_max: np.ndarray  # [m/s^3 or rad/s^3]
    jerk: bool  # jerk-limited (the raw plan filtered, `jerk_filter`); otherwise trapezoids
    filter_n: int  # samples averaged by the jerk filter (1: no filter)
    window_s: float  # [s] T = (filter_n - 1) * period, the span it averages over (0: none)
    period_s: float  # [s] interpolation period: the sampled positions' spacing in time

    @classmethod
    def of(cls, config: NcConfig) -> AxisLimits:
        a_max = np.array(config.a_max)
        j_max = np.array(config.j_max)
        jerk = config.profile == "jerk"
        period = config.interpolation_period_s
        n = filter_samples(a_max, j_max, period) if jerk else 1
        if jerk:  # the filtered plan runs exactly at the limits: keep its rounding inside
            a_max = a_max * (1.0 - FILTER_ROUNDING)
            j_max = j_max * (1.0 - FILTER_ROUNDING)
        return cls(
            v_max=np.array(config.v_max),
            rapid=np.array(config.rapid),
            a_max=a_max,
            j_max=j_max,
            jerk=jerk,
            filter_n=n,
            window_s=(n - 1) * period,
            period_s=period,
        )

    def cruise_cap(
        self,
        a_coef: np.ndarray,
        j_coef: np.ndarray,
        a_share: float,
        j_share: float,
        kick: np.ndarray | None = None,
    ) -> np.ndarray:
        """Highest speed v with coef*v^2 <= a_share*a_max and coef*v^3 + c v^2 <= j_share*j_max
        on every axis (coefficients over the last dimension), c = KICK_WEIGHT * kick / period
        from the curvature steps `kick` [1/m] (`kick_jerk`)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            cap = np.min(
                np.where(a_coef > 0.0, np.sqrt(a_share * self.a_max / a_coef), np.inf), axis=-1
            )
            if self.jerk:
                budget = j_share * self.j_max
                c = np.zeros_like(j_coef) if kick is None else self.kick_jerk(kick)
                j_cap = _cubic_cap(j_coef, c, budget)
                cap = np.minimum(cap, np.min(j_cap, axis=-1))
        return cap

    def kick_jerk(self, kick: np.ndarray) -> np.ndarray:
        """Coefficient c [1/(m s)] of the sampled jerk c v^2 of curvature steps `kick` [1/m]."""
        return KICK_WEIGHT * kick / self.period_s


def _cubic_cap(j: np.ndarray, c: np.ndarray, budget: np.ndarray) -> np.ndarray:
    """Largest v >= 0 with j v^3 + c v^2 <= budget (j, c >= 0; inf where both are 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.minimum(
            np.where(j > 0.0, np.cbrt(budget / j), np.inf),
            np.where(c > 0.0, np.sqrt(budget / c), np.inf),
        )
        both = (j > 0.0) & (c > 0.0)
        x = np.where(both, v, 1.0)
        for _ in range(CUBIC_NEWTON_STEPS):  # from above: F convex and rising, stays above
            x = x - (j * x**3 + c * x * x - budget) / (3.0 * j * x * x + 2.0 * c * x)
        x = x * (1.0 - 1e-12)  # below the root, not on it
    return np.where(both, x, v)


@dataclass(frozen=True, kw_only=True)
class MoveLimits:
    """The polyline of the listed moves and the limits along each move k (arrays of n)."""

    P: np.ndarray  # (n+1, n_axes) [m] vertices; move k runs from P[k] to P[k+1]
    L: np.ndarray  # (n,) [m] move lengths over all axes
    u: np.ndarray  # (n, n_axes) unit directions
    V: np.ndarray  # (n,) [m/s] speed cap along the move (feed or rapid)
    A: np.ndarray  # (n,) [m/s^2] acceleration of s'' that keeps every axis within a_max
    J: np.ndarray  # (n,) [m/s^3] jerk of s''' that keeps every axis within j_max (inf: no limit)


def move_limits(
    points: list[tuple[float, ...]] | np.ndarray,
    rapids: list[bool],
    feeds: list[float],
    limits: AxisLimits,
) -> MoveLimits:
    """Limits along the moves between consecutive `points` (one more point than moves)."""
    n = len(rapids)
    P = np.array(points)
    delta = np.diff(P, axis=0)
    L = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    u = delta / L[:, None]
    absu = np.abs(u)
    with np.errstate(divide="ignore"):
        v_feed = np.min(limits.v_max / absu, axis=1)
        v_rapid = np.min(limits.rapid / absu, axis=1)
        A = np.min(limits.a_max / absu, axis=1)
        J = np.min(limits.j_max / absu, axis=1)
    V = np.where(np.array(rapids), v_rapid, np.minimum(np.array(feeds), v_feed))
    if not limits.jerk:
        J = np.full(n, np.inf)
    return MoveLimits(P=P, L=L, u=u, V=V, A=A, J=J)


def filter_samples(a_max: np.ndarray, j_max: np.ndarray, period: float) -> int:
    """Samples N the jerk filter averages (`jerk_filter`): (N - 1) * period >= max_i a_i / j_i."""
    span = float(np.max(a_max / j_max))
    return math.ceil(span / period - 1e-9) + 1
