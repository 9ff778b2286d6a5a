"""Figures of a sampled multi-axis trajectory against the program's programmed path.

Any controller's setpoints can be measured, ours or another's (`benchmarks/linuxcnc_peer.py`
compares feed_twin.gcode with LinuxCNC): only positions at t = k*T and, where known, the
program line of each sample are used, and every derivative is a difference of positions, so
both sides are measured the same way.

- Path distance: the distance of each sample from the programmed path (lines and true arcs,
  `geometry.programmed_path`), looked for near the segment of the sample's program line.
- Corners (junctions turning by more than CORNER_MIN_RAD without a stop): the closest approach
  of the path to the programmed corner point, on a cubic Hermite curve through the samples
  (central-difference tangents), and the path speed there.
- Arcs: the distance from the programmed circle or helix of every sample that belongs to an
  arc and lies outside the blends of its non-tangent ends.
- Program time from the first to the last moving sample; peak |velocity|, |acceleration| and
  |jerk| per axis from first, second and third differences of the positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feed_twin.gcode.geometry import PathSegment
from feed_twin.gcode.trajectory import SampledTrajectory

MOVING_STEP_M = 1e-12  # [m] a step between samples above this is motion
CORNER_MIN_RAD = math.radians(0.5)  # junctions turning less are tangent, not corners
LINE_WINDOW = 2  # segments before and after the sample's line's segment that are searched
REASSIGN_DISTANCE_M = 2e-6  # [m] a sample this far from its line's segments is searched globally
HERMITE_POINTS = 33  # points per sample interval where the closest approach is refined
ZONE_FACTOR = 1.5  # margin on the reach of a corner blend (samples nearer are the corner's)
# The closest approach to a corner is read from 1 kHz samples: our planner's corners measure
# up to 0.5 % above what the same plan sampled at 10 kHz gives (a 90 degree blend of 10 um is
# crossed in about 8 samples), so a corner passes up to this share above its tolerance.
CORNER_RESOLUTION = 0.01


@dataclass(frozen=True, kw_only=True)
class Corner:
    """A blended junction of the programmed path: segment `index` meets segment `index + 1`."""

    index: int
    line: int  # source line of the segment that ends here
    vertex_m: tuple[float, ...]  # [m] the programmed corner point
    angle_rad: float  # [rad] turn of the direction of travel
    tolerance_m: float  # [m] allowed deviation (G64 P)
    zone_m: float  # [m] samples nearer than this to the vertex belong to the corner's blend


@dataclass(frozen=True, kw_only=True)
class TrajectoryFigures:
    """What `trajectory_figures` measures; per-axis tuples follow the trajectory's axes."""

    program_time_s: float  # [s] first to last moving sample
    path_dev_max_m: float  # [m] largest distance of a sample from the programmed path
    path_dev_rms_m: float  # [m] RMS of that distance over the moving samples
    corners: tuple[Corner, ...]
    corner_dev_m: tuple[float, ...]  # [m] closest approach to each corner's vertex
    corner_speed_m_s: tuple[float, ...]  # [m/s] path speed there
    arc_dev_max_m: float  # [m] largest distance of an arc sample from its circle (0: no arcs)
    arc_samples: int  # samples that count as arc samples
    peak_vel_m_s: tuple[float, ...]  # [m/s] per axis
    peak_acc_m_s2: tuple[float, ...]  # [m/s^2] per axis
    peak_jerk_m_s3: tuple[float, ...]  # [m/s^3] per axis

    @property
    def corner_dev_max_m(self) -> float:
        """[m] the largest corner deviation; nan when a corner had no samples near it."""
        if any(math.isnan(d) for d in self.corner_dev_m):
            return math.nan
        return max(self.corner_dev_m, default=0.0)


def blended_corners(segments: tuple[PathSegment, ...]) -> tuple[Corner, ...]:
    """Junctions that turn by more than CORNER_MIN_RAD and where the path does not stop.

    The zone is a bound on how far from the vertex a blend within the tolerance can reach:
    a blend with a triangular curvature profile reaches 3 tol / sin(angle/2) (feed_twin), a
    circular one tol / tan(angle/4) (LinuxCNC); the larger, with a margin.
    """
    corners: list[Corner] = []
    for k in range(len(segments) - 1):
        segment = segments[k]
        if segment.stops_after:
            continue
        cosine = float(np.dot(segment.tangent(1.0), segments[k + 1].tangent(0.0)))
        angle = math.acos(min(1.0, max(-1.0, cosine)))
        if angle <= CORNER_MIN_RAD:
            continue
        tol = segment.tolerance_m
        reach = tol * max(3.0 / math.sin(0.5 * angle), 1.0 / math.tan(0.25 * angle))
        corners.append(
            Corner(
                index=k,
                line=segment.line,
                vertex_m=segment.end_m,
                angle_rad=angle,
                tolerance_m=tol,
                zone_m=ZONE_FACTOR * reach,
            )
        )
    return tuple(corners)


def segment_distance(points: np.ndarray, segment: PathSegment) -> np.ndarray:
    """Distance [m] of each point (m, n_axes) from one programmed segment."""
    start = np.array(segment.start_m)
    end = np.array(segment.end_m)
    if segment.arc is None:
        d = end - start
        dd = float(d @ d)
        if dd == 0.0:
            return np.linalg.norm(points - start, axis=1)
        f = np.clip((points - start) @ d / dd, 0.0, 1.0)
        return np.linalg.norm(points - start - f[:, None] * d, axis=1)
    arc = segment.arc
    i1, i2, _ = arc.plane_axes
    rel1 = points[:, i1] - arc.centre_m[0]
    rel2 = points[:, i2] - arc.centre_m[1]
    rho = np.hypot(rel1, rel2)
    phi = np.arctan2(rel2, rel1)
    direction = math.copysign(1.0, arc.sweep_rad)
    span = abs(arc.sweep_rad)
    # Angle travelled from the start in the sweep's direction; every turn of a helix a candidate.
    base = np.mod(direction * (phi - arc.theta0_rad), 2.0 * math.pi)
    turns = np.arange(math.ceil(span / (2.0 * math.pi)) + 1)
    f = (base[:, None] + 2.0 * math.pi * turns) / span  # (m, K)
    r = arc.r_start_m + (arc.r_end_m - arc.r_start_m) * f
    radial = rho[:, None] - r
    # Off the plane (the normal and any other axis) the point moves linearly in f; a residual
    # there counts only across the helix, whose slope is |axial| / r per radian.
    axial = end - start
    axial[[i1, i2]] = 0.0
    rate = axial / span  # [m/rad]
    resid = points[:, None, :] - (start + f[..., None] * axial)
    resid[..., [i1, i2]] = 0.0
    along = resid @ rate
    across2 = np.einsum("mkd,mkd->mk", resid, resid) - along**2 / (r * r + float(rate @ rate))
    d = np.sqrt(radial**2 + np.maximum(across2, 0.0))
    d = np.where(f <= 1.0, d, np.inf)
    ends = np.minimum(np.linalg.norm(points - start, axis=1), np.linalg.norm(points - end, axis=1))
    return np.minimum(np.min(d, axis=1), ends)


def nearest_segments(
    pos_m: np.ndarray, line: np.ndarray | None, segments: tuple[PathSegment, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """(segment index, distance [m]) of each sample's nearest programmed segment.

    With program lines, only the segments within LINE_WINDOW of the line's segment are
    searched (a path that passes a place twice is not mistaken for itself); samples that end
    up farther than REASSIGN_DISTANCE_M from those are searched over all segments.
    """
    n = len(pos_m)
    m = len(segments)
    seg_lines = np.array([s.line for s in segments])
    best = np.full(n, np.inf)
    index = np.zeros(n, dtype=np.int64)
    if line is not None and np.all(np.diff(seg_lines) >= 0):
        own = np.clip(np.searchsorted(seg_lines, line, side="right") - 1, 0, m - 1)
        offsets = np.arange(-LINE_WINDOW, LINE_WINDOW + 1)
        candidates = np.clip(own[:, None] + offsets, 0, m - 1).ravel()
        samples = np.repeat(np.arange(n), len(offsets))
        # the distinct (segment, sample) pairs, by segment then sample: one integer key each
        # (a row-wise unique sorts the pairs as opaque records, ten times slower)
        pairs = np.unique(candidates * n + samples)
        bounds = np.searchsorted(pairs, np.arange(m + 1) * n)
        for k in range(m):
            rows = pairs[bounds[k] : bounds[k + 1]] - k * n
            if len(rows):
                _take_nearer(best, index, rows, segment_distance(pos_m[rows], segments[k]), k)
        far = np.flatnonzero(best > REASSIGN_DISTANCE_M)
    else:
        far = np.arange(n)
    if len(far):
        for k in range(m):
            _take_nearer(best, index, far, segment_distance(pos_m[far], segments[k]), k)
    return index, best


def _take_nearer(
    best: np.ndarray, index: np.ndarray, rows: np.ndarray, dist: np.ndarray, k: int
) -> None:
    nearer = dist < best[rows]
    best[rows[nearer]] = dist[nearer]
    index[rows[nearer]] = k


def _closest_approach(pos: np.ndarray, period: float, i: int, vertex: np.ndarray) -> float:
    """Distance [m] of the vertex from the Hermite curve through the samples around i."""
    n = len(pos)
    lo, hi = max(i - 1, 0), min(i + 1, n - 1)
    best = float(np.linalg.norm(pos[i] - vertex))
    s = np.linspace(0.0, 1.0, HERMITE_POINTS)[:, None]
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    for a in range(lo, hi):
        b = a + 1
        # Central-difference tangents (one-sided at the ends of the record), times the period.
        m_a = 0.5 * (pos[min(b, n - 1)] - pos[max(a - 1, 0)])
        m_b = 0.5 * (pos[min(b + 1, n - 1)] - pos[a])
        curve = h00 * pos[a] + h10 * m_a + h01 * pos[b] + h11 * m_b
        best = min(best, float(np.min(np.linalg.norm(curve - vertex, axis=1))))
    return best


def trajectory_figures(
    traj: SampledTrajectory, segments: tuple[PathSegment, ...], *, use_lines: bool = True
) -> TrajectoryFigures:
    """Measure a trajectory sampled at a constant period against its programmed segments."""
    n = len(traj)
    if n < 4:
        raise ValueError(f"len(traj) = {n}: needs at least 4 samples")
    if not segments:
        raise ValueError("segments = (): the program has no moves")
    if traj.pos_m.shape[1] != len(segments[0].start_m):
        raise ValueError(
            f"pos_m has {traj.pos_m.shape[1]} axes: the segments have {len(segments[0].start_m)}"
        )
    period = float(traj.t_s[1] - traj.t_s[0])
    steps = np.diff(traj.t_s)
    if period <= 0.0 or np.max(np.abs(steps - period)) > 1e-6 * period:
        raise ValueError(
            f"t_s: samples must be evenly spaced (steps {steps.min():.6g}..{steps.max():.6g} s)"
        )
    pos = traj.pos_m
    moving_step = np.linalg.norm(np.diff(pos, axis=0), axis=1) > MOVING_STEP_M
    moving = np.zeros(n, dtype=bool)
    moving[1:] |= moving_step
    moving[:-1] |= moving_step
    active = np.flatnonzero(moving_step)
    program_time = float(traj.t_s[active[-1] + 1] - traj.t_s[active[0]]) if len(active) else 0.0

    seg, dist = nearest_segments(pos, traj.line if use_lines else None, segments)
    rms = float(np.sqrt(np.mean(dist[moving] ** 2))) if np.any(moving) else 0.0

    corners = blended_corners(segments)
    corner_dev: list[float] = []
    corner_speed: list[float] = []
    in_zone = np.zeros(n, dtype=bool)
    for corner in corners:
        vertex = np.array(corner.vertex_m)
        to_vertex = np.linalg.norm(pos - vertex, axis=1)
        own_seg = (seg == corner.index) | (seg == corner.index + 1)
        if use_lines:
            # A vertex the path passes twice (a square drawn again from the same point): a
            # sample off both segments by more than REASSIGN_DISTANCE_M may have been given to
            # the other visit's segments; its program line still says which corner it is at.
            lines = (corner.line, segments[corner.index + 1].line)
            own_seg |= np.isin(traj.line, lines) & (to_vertex < corner.zone_m)
        own = np.flatnonzero(own_seg)
        in_zone[own[to_vertex[own] < corner.zone_m]] = True
        if len(own) == 0:
            corner_dev.append(math.nan)
            corner_speed.append(math.nan)
            continue
        i = int(own[np.argmin(to_vertex[own])])
        corner_dev.append(_closest_approach(pos, period, i, vertex))
        lo, hi = max(i - 1, 0), min(i + 1, n - 1)
        corner_speed.append(float(np.linalg.norm(pos[hi] - pos[lo]) / ((hi - lo) * period)))

    is_arc = np.array([s.arc is not None for s in segments])
    arc_rows = np.flatnonzero(is_arc[seg] & moving & ~in_zone)
    arc_dev = float(np.max(dist[arc_rows])) if len(arc_rows) else 0.0

    def peak(order: int) -> tuple[float, ...]:
        return tuple(float(x) for x in np.max(np.abs(np.diff(pos, order, axis=0)), axis=0))

    return TrajectoryFigures(
        program_time_s=program_time,
        path_dev_max_m=float(np.max(dist)),
        path_dev_rms_m=rms,
        corners=corners,
        corner_dev_m=tuple(corner_dev),
        corner_speed_m_s=tuple(corner_speed),
        arc_dev_max_m=arc_dev,
        arc_samples=len(arc_rows),
        peak_vel_m_s=tuple(v / period for v in peak(1)),
        peak_acc_m_s2=tuple(a / period**2 for a in peak(2)),
        peak_jerk_m_s3=tuple(j / period**3 for j in peak(3)),
    )


def requirement_failures(figures: TrajectoryFigures, *, chord_tolerance_m: float) -> list[str]:
    """What the trajectory breaks: arc samples off their circle, corners beyond tolerance."""
    failures: list[str] = []
    if figures.arc_dev_max_m > chord_tolerance_m:
        failures.append(
            f"arc sample {figures.arc_dev_max_m * 1e6:.3f} um from its circle "
            f"(chord_tolerance_m {chord_tolerance_m * 1e6:.3f} um)"
        )
    for corner, dev in zip(figures.corners, figures.corner_dev_m, strict=True):
        if not dev <= corner.tolerance_m * (1.0 + CORNER_RESOLUTION):
            failures.append(
                f"corner at line {corner.line} ({math.degrees(corner.angle_rad):.1f} deg): "
                f"{dev * 1e6:.3f} um from the vertex (tolerance {corner.tolerance_m * 1e6:.3f} um)"
            )
    return failures


LIMIT_SLACK = 1e-6  # relative; differences of positions at rounding level stay inside


def axis_limit_failures(
    figures: TrajectoryFigures,
    axes: tuple[str, ...],
    *,
    v_max: tuple[float, ...],
    a_max: tuple[float, ...],
    j_max: tuple[float, ...] | None,
) -> list[str]:
    """Axes whose peak velocity, acceleration or (with `j_max`) jerk, from differences of the
    sampled positions, exceed their limits."""
    checks = [("velocity", figures.peak_vel_m_s, v_max, "m/s")]
    checks.append(("acceleration", figures.peak_acc_m_s2, a_max, "m/s^2"))
    if j_max is not None:
        checks.append(("jerk", figures.peak_jerk_m_s3, j_max, "m/s^3"))
    failures: list[str] = []
    for kind, peaks, limits, unit in checks:
        for axis, peak, limit in zip(axes, peaks, limits, strict=True):
            if peak > limit * (1.0 + LIMIT_SLACK):
                failures.append(f"axis {axis}: peak {kind} {peak:.6g} {unit} above {limit:.6g}")
    return failures
