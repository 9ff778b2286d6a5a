"""What the interpreter hands the planner: straight moves, stops and events (SI)."""

from __future__ import annotations

from typing import NamedTuple

from feed_twin.gcode.arcs import Arc


class Move(NamedTuple):
    """A straight move to a machine position (arcs arrive as chords)."""

    line: int
    end_m: tuple[float, ...]  # [m] machine coordinates, one per configured axis
    rapid: bool  # G0: per-axis rapid rates; otherwise the programmed feed
    feed_m_s: float  # programmed feed (0 for rapids) along the move's length over all axes
    # (m and rad): the F of XYZ moves; see `interpreter` on rotary axes
    tolerance_m: float  # [m] allowed corner deviation at the end of this move (G64)
    exact_stop: bool  # stop at the end of this move (G61, G9)
    arc: Arc | None = None  # the programmed arc this move is a chord of


class Stop(NamedTuple):
    """The path stops here for a while (G4, and M-codes a control executes at standstill)."""

    line: int
    dwell_s: float  # [s] time spent at standstill


class Event(NamedTuple):
    """Something the recording shows (spindle, tool, coolant, pauses, warnings)."""

    line: int
    kind: str
    value: float
    text: str
    stops: bool  # the path comes to rest before the event happens


Item = Move | Stop | Event
