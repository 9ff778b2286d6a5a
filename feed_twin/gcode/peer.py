"""One program on two planners: figures of each side and what they must agree on.

A side is a planner that ran the program (its sampled setpoints) or refused it (its message).
Both are measured against the same programmed path (`geometry.programmed_path`) by
`metrics.trajectory_figures`; `compare` lists the requirements a side breaks (arc samples off
the circle by more than chord_tolerance_m, blended corners beyond their G64 tolerance) and the
program time of a side against the reference's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from feed_twin.gcode.geometry import PathSegment
from feed_twin.gcode.metrics import TrajectoryFigures, requirement_failures, trajectory_figures
from feed_twin.gcode.trajectory import SampledTrajectory

TIME_TOLERANCE = 0.05  # program times within 5 % of the reference's where the limits are the same
JERK_TIME_LIMIT = 1.10  # a jerk-limited plan within 1.10 times an acceleration-limited one's time


@dataclass(frozen=True, kw_only=True)
class Side:
    """One planner's result for one program."""

    name: str
    error: str | None  # the planner's message when it refused the program
    figures: TrajectoryFigures | None
    failures: tuple[str, ...]  # requirements the trajectory breaks

    @property
    def accepted(self) -> bool:
        return self.error is None


def measure_side(
    name: str,
    result: SampledTrajectory | str,
    segments: tuple[PathSegment, ...],
    *,
    chord_tolerance_m: float,
) -> Side:
    """Figures and broken requirements of a trajectory, or the refusal message."""
    if isinstance(result, str):
        return Side(name=name, error=result, figures=None, failures=())
    figures = trajectory_figures(result, segments)
    failures = requirement_failures(figures, chord_tolerance_m=chord_tolerance_m)
    return Side(name=name, error=None, figures=figures, failures=tuple(failures))


def acceptance_mismatch(sides: list[Side]) -> str | None:
    """A one-line report when some sides ran the program and others refused it."""
    refused = [s for s in sides if not s.accepted]
    if not refused or len(refused) == len(sides):
        return None
    ran = ", ".join(s.name for s in sides if s.accepted)
    why = "; ".join(f"{s.name}: {s.error}" for s in refused)
    return f"accepted by {ran} only ({why})"


def time_ratio(side: Side, reference: Side) -> float | None:
    """Program time of a side over the reference's (None when either did not run it)."""
    if side.figures is None or reference.figures is None:
        return None
    if reference.figures.program_time_s <= 0.0:
        return None
    return side.figures.program_time_s / reference.figures.program_time_s


def side_summary(side: Side) -> dict[str, Any]:
    """The side's figures as plain numbers (SI) for a JSON report."""
    if side.figures is None:
        return {"accepted": False, "error": side.error}
    f = side.figures
    speeds = [v for v in f.corner_speed_m_s if not math.isnan(v)]
    return {
        "accepted": True,
        "program_time_s": round(f.program_time_s, 4),
        "path_dev_max_m": f.path_dev_max_m,
        "path_dev_rms_m": f.path_dev_rms_m,
        "corners": len(f.corners),
        # JSON has no nan: a corner without samples near it is null (and a broken requirement)
        "corner_dev_max_m": None if math.isnan(f.corner_dev_max_m) else f.corner_dev_max_m,
        "corner_speed_mean_m_s": sum(speeds) / len(speeds) if speeds else None,
        "arc_dev_max_m": f.arc_dev_max_m,
        "arc_samples": f.arc_samples,
        "peak_vel_m_s": [round(v, 6) for v in f.peak_vel_m_s],
        "peak_acc_m_s2": [round(a, 4) for a in f.peak_acc_m_s2],
        "peak_jerk_m_s3": [round(j, 1) for j in f.peak_jerk_m_s3],
        "failures": len(side.failures),
        "first_failure": side.failures[0] if side.failures else None,
    }
