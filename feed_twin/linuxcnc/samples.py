"""What LinuxCNC's servo thread records each period, and the recording in SI units.

The HAL `sampler` in the servo thread writes one row per period into a FIFO (at most 21 pins,
HAL_STREAM_MAX_PINS); the headless display program (`_display.py`) drains it about every
0.2 ms and forwards each row as float64 `[receive time, pin values...]` (CLOCK_MONOTONIC
seconds). Two of the pins come from `feedtwin_clock` (config/linuxcnc/feedtwin_clock.comp), the
first function of the servo thread: the period's index and its start time. `ServoTrace` turns
the rows into per-tick arrays: time = tick * period (never the wall clock), millimetres ->
metres, and lost samples counted from gaps in the tick index.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from feed_twin.linuxcnc.period_timing import PeriodTiming, period_timing

if TYPE_CHECKING:
    from feed_twin.gcode.trajectory import SampledTrajectory

JOINT_LETTERS = ("x", "y", "z")
M_PER_MM = 1e-3
# The first two float64 of each forwarded row, before the pin values.
ROW_HEADER = ("receive_time_s",)


@dataclass(frozen=True, kw_only=True)
class Column:
    """One sampled pin: its HAL signal, sampler type letter and the factor to SI."""

    name: str  # column name in the trace, e.g. "x.pos_cmd"
    signal: str  # the HAL signal the sampler pin joins
    hal_type: str  # sampler cfg letter: f float, s s32, b bit, u u32
    to_si: float  # [SI unit per LinuxCNC unit] (1e-3 for mm, mm/s, mm/s^2)


# joint quantity -> (signal suffix, factor to SI); the PID output is a velocity (mm/s).
_JOINT_COLUMNS = (
    ("pos_cmd", "joint-pos-cmd"),  # joint.N.pos-cmd, machine coordinates [mm]
    ("vel_cmd", "vel-cmd"),  # joint.N.vel-cmd [mm/s]
    ("acc_cmd", "acc-cmd"),  # joint.N.acc-cmd [mm/s^2]
    ("pos_fb", "joint-pos-fb"),  # joint.N.pos-fb, machine coordinates [mm]
    ("f_error", "f-error"),  # joint.N.f-error [mm]
    ("pid_output", "output"),  # pid.L.output, the velocity command to the drive [mm/s]
)
JOINT_QUANTITIES = tuple(q for q, _ in _JOINT_COLUMNS)


@dataclass(frozen=True, kw_only=True)
class SampleLayout:
    columns: tuple[Column, ...]

    @property
    def hal_cfg(self) -> str:
        return "".join(c.hal_type for c in self.columns)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.columns)

    def index(self, name: str) -> int:
        return self.names.index(name)

    @property
    def row_width(self) -> int:
        return len(ROW_HEADER) + len(self.columns)


def sample_layout() -> SampleLayout:
    """The sampler's columns: six per joint, the program line, the tick index and time."""
    columns = [
        Column(
            name=f"{letter}.{quantity}", signal=f"{letter}-{suffix}", hal_type="f", to_si=M_PER_MM
        )
        for letter in JOINT_LETTERS
        for quantity, suffix in _JOINT_COLUMNS
    ]
    columns += [
        Column(name="program_line", signal="program-line", hal_type="s", to_si=1.0),
        Column(name="tick", signal="tick", hal_type="s", to_si=1.0),
        Column(name="tick_time_s", signal="tick-time", hal_type="f", to_si=1.0),
    ]
    if len(columns) > 21:
        raise ValueError(f"sample layout has {len(columns)} pins: HAL streams carry at most 21")
    return SampleLayout(columns=tuple(columns))


@dataclass(frozen=True, kw_only=True)
class ServoTrace:
    """Every recorded servo period of one run, SI units, one row per tick.

    `tick` counts servo periods from the first recorded one; `t_s` = tick * period. Joint arrays
    have shape (n, 3) with columns X, Y, Z; positions are machine coordinates (LinuxCNC's joint
    positions; the motor positions of HAL differ by the offset homing set)."""

    period_s: float  # [s] servo period
    tick: np.ndarray  # [-] servo period index (int64)
    t_s: np.ndarray  # [s] tick * period_s
    pos_cmd_m: np.ndarray  # [m] (n, 3) commanded position
    vel_cmd_m_s: np.ndarray  # [m/s] (n, 3) commanded velocity
    acc_cmd_m_s2: np.ndarray  # [m/s^2] (n, 3) commanded acceleration
    pos_fb_m: np.ndarray  # [m] (n, 3) position feedback
    f_error_m: np.ndarray  # [m] (n, 3) LinuxCNC's following error (command - feedback)
    pid_output_m_s: np.ndarray  # [m/s] (n, 3) PID output (velocity command to the drive)
    program_line: np.ndarray  # [-] motion.program-line (int64; 0 outside a program)
    tick_time_s: np.ndarray  # [s] CLOCK_MONOTONIC when the period started
    receive_time_s: np.ndarray  # [s] CLOCK_MONOTONIC when the reader took the row
    samples_lost: int  # rows missing between the first and the last (gaps in the tick index)

    @property
    def samples(self) -> int:
        return int(self.tick.size)

    def program_span(self) -> slice:
        """Rows from the first period with a program line on the motion controller to the last
        period whose command still moves (the line drops to 0 one period before the last
        motion ends). A dwell before the first motion of a program is not on it."""
        running = np.flatnonzero(self.program_line != 0)
        if running.size == 0:
            return slice(0, 0)
        moving = np.flatnonzero(np.any(np.diff(self.pos_cmd_m, axis=0) != 0.0, axis=1)) + 1
        last = max(int(running[-1]), int(moving[-1]) if moving.size else 0)
        return slice(int(running[0]), last + 1)

    @property
    def program_time_s(self) -> float:
        """[s] from the program's first motion to its last (periods times the period)."""
        span = self.program_span()
        return (span.stop - span.start) * self.period_s

    def cut(self, rows: slice) -> ServoTrace:
        """The rows `rows` with the ticks counted from the first of them."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name, value in fields.items():
            if isinstance(value, np.ndarray):
                fields[name] = value[rows]
        fields["tick"] = fields["tick"] - (fields["tick"][0] if fields["tick"].size else 0)
        fields["t_s"] = fields["tick"] * self.period_s
        ticks = fields["tick"]
        fields["samples_lost"] = int(ticks[-1] + 1 - ticks.size) if ticks.size else 0
        return ServoTrace(**fields)

    def period_timing(self) -> PeriodTiming:
        """Start lateness and jitter of the recorded periods (feed_twin.linuxcnc.period_timing)."""
        return period_timing(self.tick, self.tick_time_s, period_s=self.period_s)

    @property
    def reader_latency_s(self) -> np.ndarray:
        """[s] servo tick -> row in the reader's hands."""
        return self.receive_time_s - self.tick_time_s

    def commanded_trajectory(self, axes: tuple[str, ...]) -> SampledTrajectory:
        """LinuxCNC's commanded joint motion as setpoints to measure (joints X, Y, Z = `axes`);
        its program line is motion's, which `gcode.metrics` uses to find each sample's segment.
        """
        # imported here: the G-code package compiles its planner, which a trace need not pay for
        from feed_twin.gcode.trajectory import SampledTrajectory

        return SampledTrajectory(
            t_s=self.t_s,
            axes=axes,
            pos_m=self.pos_cmd_m,
            vel_m_s=self.vel_cmd_m_s,
            acc_m_s2=self.acc_cmd_m_s2,
            line=self.program_line,
            events=(),
        )


def rows_to_trace(rows: np.ndarray, layout: SampleLayout, *, period_s: float) -> ServoTrace:
    """Per-tick arrays from forwarded rows (shape (n, layout.row_width), float64)."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, layout.row_width)
    values = rows[:, len(ROW_HEADER) :]
    index = values[:, layout.index("tick")].astype(np.int64)
    if index.size and np.any(np.diff(index) <= 0):
        raise ValueError("tick indices are not increasing: rows from two runs or reordered")
    tick = index - (int(index[0]) if index.size else 0)
    lost = int(tick[-1] + 1 - tick.size) if tick.size else 0

    def column(name: str) -> np.ndarray:
        c = layout.index(name)
        return values[:, c] * layout.columns[c].to_si

    def joints(quantity: str) -> np.ndarray:
        return np.stack([column(f"{letter}.{quantity}") for letter in JOINT_LETTERS], axis=1)

    return ServoTrace(
        period_s=period_s,
        tick=tick,
        t_s=tick * period_s,
        pos_cmd_m=joints("pos_cmd"),
        vel_cmd_m_s=joints("vel_cmd"),
        acc_cmd_m_s2=joints("acc_cmd"),
        pos_fb_m=joints("pos_fb"),
        f_error_m=joints("f_error"),
        pid_output_m_s=joints("pid_output"),
        program_line=column("program_line").astype(np.int64),
        tick_time_s=column("tick_time_s"),
        receive_time_s=rows[:, 0].copy(),
        samples_lost=lost,
    )
