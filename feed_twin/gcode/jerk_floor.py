# pyright: reportConstantRedefinition=false
# (A, J, V, D are the field's symbols for acceleration, jerk, speed and distance)
"""What a jerk limit must cost beyond an acceleration-limited plan: a floor for the jerk profile.

An acceleration-limited plan (our trapezoid profile, or LinuxCNC's) changes speed by dv in
dv / A. Under a jerk limit J the quickest change from rest-in-acceleration to rest-in-
acceleration (a = 0 at both ends: a near-stop is a speed minimum, and a is continuous) is the
S-curve of duration

    tau_J(dv) = dv / A + A / J   (dv >= A^2 / J),   2 sqrt(dv / J)   (dv < A^2 / J)

and by its symmetry it covers (v0 + v1) / 2 * tau_J(dv). Between two near-stops (speed minima
v_a, v_b well below the speed reached between them, the stretch D long, speed cap V) the
quickest 1-D motion rises with one S-curve to a peak v_p <= V, cruises, and falls with another
(Biagiotti and Melchiorri, "Trajectory Planning for Automatic Machines and Robots", 2008, the
double-S profile); the acceleration-limited one does the same with tau_A(dv) = dv / A. Their
difference is what the jerk limit costs on that stretch: T = A / J per full speed change,
2 (sqrt(F / J) - F / (2 A)) for a stop-and-go from F < A^2 / J.

`jerk_floor_extra` finds the near-stops of an acceleration-limited sampled plan (speed minima
at most NEAR_STOP times the lower of the peaks on either side, the program's start and end
included) and sums that difference over the stretches between them, each with the largest
path acceleration any of its directions allows (min_i a_max_i / |u_i|, which makes the
difference smallest) and J = A times the largest j_max_i / a_max_i. The plan's time plus this
sum is the floor the benchmark reports: a bound where the stretches are straight lines between
sharp corners (the corner speeds are the acceleration-limited plan's, higher than a jerk limit
allows within the same tolerance), an underestimate on curves, whose speed caps the jerk limit
lowers (x''' = v^3 / R^2 on a circle) and whose small speed changes it makes dearer; neither
is counted.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from feed_twin.gcode.trajectory import SampledTrajectory

NEAR_STOP = 0.5  # a speed minimum at most this share of the peaks on both sides is a near-stop
PEAK_BISECTION_STEPS = 60  # bisection of the peak speed of a stretch (to 1e-18 of V)


def change_time(dv: np.ndarray, A: np.ndarray, J: np.ndarray) -> np.ndarray:
    """[s] Quickest change of speed by dv >= 0 at |a| <= A, |j| <= J, a = 0 at both ends
    (J = inf: acceleration-limited, dv / A)."""
    finite = np.isfinite(J)
    with np.errstate(divide="ignore", invalid="ignore"):
        full = dv / A + np.where(finite, A / J, 0.0)
        short = np.where(finite, 2.0 * np.sqrt(dv / J), dv / A)
        return np.where(~finite | (dv * J >= A * A), full, short)


def stretch_time(
    D: np.ndarray,
    v_a: np.ndarray,
    v_b: np.ndarray,
    V: np.ndarray,
    A: np.ndarray,
    J: np.ndarray,
) -> np.ndarray:
    """[s] Quickest 1-D motion over D [m] from speed v_a to v_b (a = 0 at both ends), never
    above V, at |a| <= A and |j| <= J (inf: acceleration-limited): the double-S profile
    with the highest peak the length allows. Where even one S-curve from v_a to v_b needs
    more than D, the time is that of the S-curve alone."""

    def covered(vp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        t_up = change_time(vp - v_a, A, J)
        t_down = change_time(vp - v_b, A, J)
        return 0.5 * (v_a + vp) * t_up + 0.5 * (vp + v_b) * t_down, t_up + t_down

    lo = np.maximum(v_a, v_b)
    hi = np.maximum(V, lo)
    fits_top = covered(hi)[0] <= D
    for _ in range(PEAK_BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        fits = covered(mid)[0] <= D
        lo = np.where(fits, mid, lo)
        hi = np.where(fits, hi, mid)
    vp = np.where(fits_top, np.maximum(V, np.maximum(v_a, v_b)), lo)
    dist, t_changes = covered(vp)
    with np.errstate(divide="ignore", invalid="ignore"):
        cruise = np.where(vp > 0.0, np.maximum(D - dist, 0.0) / vp, 0.0)
    return t_changes + cruise


@njit(cache=True)
def _peak_beside(v: np.ndarray, k: int, step: int) -> float:
    """Highest speed from sample k on (step +-1) before a speed below v[k] or the end."""
    top = v[k]
    i = k + step
    while 0 <= i < v.shape[0] and v[i] >= v[k]:
        top = max(top, v[i])
        i += step
    return top


@njit(cache=True)
def _deep_minima(v: np.ndarray, share: float) -> np.ndarray:
    """Whether each sample is the first of a local minimum (plateaus included) at most
    `share` times the lower of the peaks beside it."""
    n = v.shape[0]
    deep = np.zeros(n, dtype=np.bool_)
    k = 1
    while k < n - 1:
        end = k
        while end + 1 < n and v[end + 1] == v[k]:
            end += 1
        if end < n - 1 and v[k - 1] > v[k] and v[end + 1] > v[k]:
            peak = min(_peak_beside(v, k, -1), _peak_beside(v, end, 1))
            deep[k] = v[k] <= share * peak
        k = end + 1
    return deep


def near_stops(speed: np.ndarray) -> np.ndarray:
    """Sample indices of the near-stops of a path speed profile, its first and last sample
    included: minima at most NEAR_STOP times the lower of the highest speeds on either side
    before a lower speed."""
    n = len(speed)
    if n < 2:
        return np.zeros(n, dtype=np.int64)
    inner = np.flatnonzero(_deep_minima(speed, NEAR_STOP))
    return np.unique(np.concatenate(([0], inner, [n - 1]))).astype(np.int64)


def jerk_floor_extra(
    trajectory: SampledTrajectory, a_max: np.ndarray, j_max: np.ndarray
) -> tuple[float, int]:
    """([s] time the jerk limit must add to the acceleration-limited `trajectory`, the number
    of its near-stops between its first and last moving samples), see the module docstring."""
    vel = trajectory.vel_m_s
    speed = np.sqrt(np.einsum("ij,ij->i", vel, vel))
    moving = np.flatnonzero(speed > 0.0)
    if len(moving) < 2:
        return 0.0, 0
    first, last = int(moving[0]) - 1, int(moving[-1]) + 1
    first, last = max(first, 0), min(last, len(speed) - 1)
    v = speed[first : last + 1]
    dt = float(np.median(np.diff(trajectory.t_s)))
    stops = near_stops(v)
    # The largest path acceleration a direction allows, and the jerk that goes with it.
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.abs(vel[first : last + 1]) / v[:, None]
        A_dir = np.min(np.where(u > 0.0, a_max / u, np.inf), axis=1)
    A_dir = np.where(np.isfinite(A_dir), A_dir, 0.0)
    a, b = stops[:-1], stops[1:]
    cum = np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)))
    D = cum[b] - cum[a]
    V = np.maximum.reduceat(v, a)
    A = np.maximum.reduceat(A_dir, a)
    keep = (D > 0.0) & (A > 0.0)
    D, V, A, v_a, v_b = D[keep], V[keep], A[keep], v[a][keep], v[b][keep]
    J = A * float(np.max(j_max / a_max))
    t_jerk = stretch_time(D, v_a, v_b, V, A, J)
    t_acc = stretch_time(D, v_a, v_b, V, A, np.full(len(D), np.inf))
    return float(np.sum(t_jerk - t_acc)), len(stops) - 2
