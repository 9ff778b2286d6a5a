"""Contour error: how far the tool point of a multi-axis twin is from the programmed path.

Per sample, with p the tool point (the twins' table positions of the simulated linear axes, the
command of the others), c the NC command at the same time and v_c its velocity:
- normal error e_n = the distance of p from the programmed path (lines and true arcs,
  gcode.geometry.programmed_path; the nearest segment found near the sample's program line,
  gcode.metrics.nearest_segments), what the part shows;
- along-path lag e_t = (c - p) . v_c / |v_c| (0 at rest): how far behind its command the tool
  runs along the path, which the part does not show.
Only the linear axes count: the tool point of a machine with rotary axes needs its kinematics,
which the NC section does not describe (a rotary axis changes the orientation of the part).
Two matched first-order loops (P position loops with gain Kv, ideal velocity loops) on a circle
of radius R at path speed v give a circle of radius R / sqrt(1 + (v/(R Kv))^2), that is a
normal error of v^2 / (2 R Kv^2) to first order, and a lag of v / Kv.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from feed_twin.gcode.geometry import PathSegment
from feed_twin.gcode.metrics import nearest_segments

MOVING_M_S = 1e-9  # [m/s] a command speed above this has a direction


@dataclass(frozen=True, kw_only=True)
class ContourError:
    """Contour error per sample; `summary` gives the figures of a run."""

    t_s: np.ndarray  # (n,) [s]
    line: np.ndarray  # (n,) program line of the command
    normal_m: np.ndarray  # (n,) [m] distance of the tool point from the programmed path
    lag_m: np.ndarray  # (n,) [m] along-path lag behind the command
    moving: np.ndarray  # (n,) bool: the command moves (the RMS is taken over these samples)

    def summary(self) -> dict[str, float | int]:
        if len(self.normal_m) == 0:
            return {"contour_error_max_m": 0.0, "contour_error_rms_m": 0.0}
        k = int(np.argmax(self.normal_m))
        rows = self.normal_m[self.moving] if np.any(self.moving) else self.normal_m
        return {
            "contour_error_max_m": float(self.normal_m[k]),
            "contour_error_rms_m": float(np.sqrt(np.mean(rows**2))),
            "contour_error_max_t_s": float(self.t_s[k]),
            "contour_error_max_line": int(self.line[k]),
            "contour_lag_max_m": float(np.max(np.abs(self.lag_m))),
        }


def linear_segments(segments: tuple[PathSegment, ...], n_linear: int) -> tuple[PathSegment, ...]:
    """The segments in the linear axes' space (arcs lie in planes of linear axes)."""
    return tuple(
        replace(s, start_m=s.start_m[:n_linear], end_m=s.end_m[:n_linear]) for s in segments
    )


def contour_error(
    t_s: np.ndarray,
    line: np.ndarray,
    tool_m: np.ndarray,
    command_m: np.ndarray,
    command_vel: np.ndarray,
    segments: tuple[PathSegment, ...],
    *,
    n_linear: int,
) -> ContourError:
    """Contour error of tool points (n, axes) against the programmed path of their command.

    `command_m` and `command_vel` are the NC's positions and velocities at the same samples;
    the first `n_linear` columns are the linear axes.
    """
    tool = np.ascontiguousarray(tool_m[:, :n_linear])
    if segments:
        _, normal = nearest_segments(tool, line, linear_segments(segments, n_linear))
    else:
        normal = np.linalg.norm(tool - command_m[:, :n_linear], axis=1)
    v = command_vel[:, :n_linear]
    speed = np.linalg.norm(v, axis=1)
    moving = speed > MOVING_M_S
    lag = np.zeros(len(tool))
    lag[moving] = (
        np.einsum("ij,ij->i", command_m[moving, :n_linear] - tool[moving], v[moving])
        / speed[moving]
    )
    return ContourError(t_s=t_s, line=line, normal_m=normal, lag_m=lag, moving=moving)
