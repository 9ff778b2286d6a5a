"""The planner's output: setpoints sampled at the interpolation period, and timed events."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class NcEvent:
    """Something that happens at a point in program time (dwell, M-code, tool, warning)."""

    t_s: float  # [s] program time at which it happens
    line: int  # source line of the block that caused it
    kind: str  # dwell, pause, optional_pause, end, spindle_cw, spindle_ccw, spindle_stop,
    # spindle_speed, tool_select, tool_change, coolant_on, coolant_off, warning
    value: float  # dwell [s], spindle speed [1/min], tool number, M-code; 0 when meaningless
    text: str  # human-readable form (the words as written, or the warning)


@dataclass(frozen=True, kw_only=True)
class SampledTrajectory:
    """Position, velocity and acceleration setpoints of every axis at t = k * period.

    `pos_m`, `vel_m_s`, `acc_m_s2` have shape (n, n_axes) in machine coordinates [m, m/s,
    m/s^2]; `line[k]` is the source line whose motion (or dwell) is active at `t_s[k]`.
    """

    t_s: np.ndarray  # (n,) [s]
    axes: tuple[str, ...]
    pos_m: np.ndarray  # (n, n_axes) [m]
    vel_m_s: np.ndarray  # (n, n_axes) [m/s]
    acc_m_s2: np.ndarray  # (n, n_axes) [m/s^2]
    line: np.ndarray  # (n,) int64
    events: tuple[NcEvent, ...]

    def __post_init__(self) -> None:
        n = self.t_s.shape[0]
        shape = (n, len(self.axes))
        for name in ("pos_m", "vel_m_s", "acc_m_s2"):
            value = getattr(self, name)
            if value.shape != shape:
                raise ValueError(f"{name}.shape = {value.shape}: must be {shape}")
        if self.line.shape != (n,):
            raise ValueError(f"line.shape = {self.line.shape}: must be ({n},)")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def axis(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position [m], velocity [m/s], acceleration [m/s^2]) of one axis."""
        try:
            i = self.axes.index(name)
        except ValueError:
            raise KeyError(f"axis {name!r} is not planned; axes are {self.axes}") from None
        return self.pos_m[:, i], self.vel_m_s[:, i], self.acc_m_s2[:, i]

    @staticmethod
    def concatenate(chunks: Iterable[SampledTrajectory]) -> SampledTrajectory:
        """Join consecutive chunks of one program (as the streaming planner yields them)."""
        parts = list(chunks)
        if not parts:
            raise ValueError("concatenate needs at least one chunk")
        axes = parts[0].axes
        return SampledTrajectory(
            t_s=np.concatenate([p.t_s for p in parts]),
            axes=axes,
            pos_m=np.concatenate([p.pos_m for p in parts]),
            vel_m_s=np.concatenate([p.vel_m_s for p in parts]),
            acc_m_s2=np.concatenate([p.acc_m_s2 for p in parts]),
            line=np.concatenate([p.line for p in parts]),
            events=tuple(e for p in parts for e in p.events),
        )
