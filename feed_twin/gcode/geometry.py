"""The programmed path of a program: its straight moves and true arcs, before any planning.

The interpreter hands the planner chords; here the chords of one G2/G3 block are joined back
into the arc they approximate, so that a trajectory (ours, or another controller's) can be
measured against the geometry the program asks for, not against our own approximation of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from feed_twin.gcode.arcs import Arc
from feed_twin.gcode.config import NcConfig
from feed_twin.gcode.interpreter import Interpreter
from feed_twin.gcode.items import Event, Move, Stop
from feed_twin.gcode.planner import iter_blocks


@dataclass(frozen=True, kw_only=True)
class PathSegment:
    """One programmed move in machine coordinates: a straight line, or an arc (`arc` set)."""

    line: int  # source line of the block
    start_m: tuple[float, ...]  # [m] start point, one entry per axis
    end_m: tuple[float, ...]  # [m] end point
    rapid: bool  # G0
    tolerance_m: float  # [m] allowed corner deviation at the end (G64 P)
    stops_after: bool  # the path is at rest at the end (G61, G9, a dwell, a stopping M-code)
    arc: Arc | None  # the programmed circle or helix; None for a straight move

    def point_at(self, f: np.ndarray) -> np.ndarray:
        """Points [m] at fractions f in [0, 1] of the segment, shape (len(f), n_axes)."""
        f = np.asarray(f, dtype=float)
        start = np.array(self.start_m)
        end = np.array(self.end_m)
        points = start + f[:, None] * (end - start)
        if self.arc is not None:
            i1, i2, _ = self.arc.plane_axes
            r = self.arc.r_start_m + (self.arc.r_end_m - self.arc.r_start_m) * f
            theta = self.arc.theta0_rad + self.arc.sweep_rad * f
            points[:, i1] = self.arc.centre_m[0] + r * np.cos(theta)
            points[:, i2] = self.arc.centre_m[1] + r * np.sin(theta)
        return points

    def tangent(self, f: float) -> np.ndarray:
        """Unit direction of travel at the fraction f."""
        start = np.array(self.start_m)
        end = np.array(self.end_m)
        d = end - start
        if self.arc is not None:
            i1, i2, _ = self.arc.plane_axes
            arc = self.arc
            r = arc.r_start_m + (arc.r_end_m - arc.r_start_m) * f
            theta = arc.theta0_rad + arc.sweep_rad * f
            dr = arc.r_end_m - arc.r_start_m
            d[i1] = dr * math.cos(theta) - r * arc.sweep_rad * math.sin(theta)
            d[i2] = dr * math.sin(theta) + r * arc.sweep_rad * math.cos(theta)
        return d / np.linalg.norm(d)


def programmed_path(source: str | Path, config: NcConfig) -> tuple[PathSegment, ...]:
    """The program's moves as segments; the chords of each arc block joined into its arc."""
    file, blocks = iter_blocks(source, config)
    interpreter = Interpreter(config, file=file)
    segments: list[PathSegment] = []
    position = config.start_position
    for item in interpreter.run(blocks):
        if type(item) is Move:
            previous = segments[-1] if segments else None
            if item.arc is not None and previous is not None and previous.arc is item.arc:
                segments[-1] = replace(previous, end_m=item.end_m, stops_after=item.exact_stop)
            else:
                segments.append(
                    PathSegment(
                        line=item.line,
                        start_m=position,
                        end_m=item.end_m,
                        rapid=item.rapid,
                        tolerance_m=item.tolerance_m,
                        stops_after=item.exact_stop,
                        arc=item.arc,
                    )
                )
            position = item.end_m
        elif segments and (type(item) is Stop or (type(item) is Event and item.stops)):
            segments[-1] = replace(segments[-1], stops_after=True)
    return tuple(segments)
