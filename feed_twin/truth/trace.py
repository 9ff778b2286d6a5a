"""The truth machine's trace stage: what a controller's trace export does to its signals.

The machine's signals come once per current period T_i, each standing for its value over that
period ((k T_i, (k+1) T_i], a zero-order hold). A trace export samples them every `period_s`
(stamped at the end of each record period), either the latest value or the MEAN over the
record period (a drive's trace averaging), each channel `delay_*_s` late (the delay snaps to
the current period), then rounds positions to the display resolution, adds measurement noise to
the effort and rounds it, turns it into a torque if asked, and flips its sign if the drive counts
current the other way round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np


@dataclass(frozen=True, kw_only=True)
class Trace:
    """How the record is made from the machine's signals."""

    period_s: float = 1.0e-3  # record sample period [s]
    average: bool = False  # True: each sample is the mean over its record period
    declare_average: bool = True  # the column map says `trace_filter: mean` when averaging
    delay_position_s: float = 0.0  # the recorded position comes this late [s]
    delay_effort_s: float = 0.0  # the recorded current comes this late [s]
    delay_command_s: float = 0.0  # the recorded setpoint comes this late [s]
    position_source: Literal["scale", "motor"] = "scale"  # table scale or motor encoder
    position_resolution_m: float = 1.0e-8  # rounding of recorded positions (scale step) [m]
    command_resolution_m: float = 1.0e-8  # rounding of the recorded setpoint [m]
    effort_noise_A: float = 0.01  # current-measurement noise, std at the record rate [A]
    effort_resolution_A: float = 0.0  # rounding of the recorded current [A]; 0: none
    effort_source: Literal["actual", "setpoint"] = "actual"  # measured i_q or its setpoint
    effort_unit: Literal["A", "Nm"] = "A"  # current, or torque through the data-sheet K_t
    effort_sign: int = 1  # -1: the drive records the current with the opposite sign

    def __post_init__(self) -> None:
        for name in ("period_s",):
            if not math.isfinite(getattr(self, name)) or getattr(self, name) <= 0.0:
                raise ValueError(f"{name} = {getattr(self, name)!r}: must be > 0")
        for name in (
            "delay_position_s",
            "delay_effort_s",
            "delay_command_s",
            "position_resolution_m",
            "command_resolution_m",
            "effort_noise_A",
            "effort_resolution_A",
        ):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f"{name} = {value!r}: must be >= 0")
        if self.effort_sign not in (1, -1):
            raise ValueError(f"effort_sign = {self.effort_sign!r}: must be 1 or -1")
        if self.position_source not in ("scale", "motor"):
            raise ValueError(f"position_source = {self.position_source!r}: 'scale' or 'motor'")
        if self.effort_source not in ("actual", "setpoint"):
            raise ValueError(f"effort_source = {self.effort_source!r}: 'actual' or 'setpoint'")
        if self.effort_unit not in ("A", "Nm"):
            raise ValueError(f"effort_unit = {self.effort_unit!r}: 'A' or 'Nm'")


def _integral(y: np.ndarray, fast_s: float, t: np.ndarray) -> np.ndarray:
    """Integral from 0 to t of the zero-order-hold signal y (y[k] over (k T, (k+1) T]), held
    at y[0] before 0 and at y[-1] after the end."""
    cum = np.concatenate([[0.0], np.cumsum(y) * fast_s])
    end = len(y) * fast_s
    inside = np.interp(np.clip(t, 0.0, end), np.arange(len(cum)) * fast_s, cum)
    return inside + np.minimum(t, 0.0) * y[0] + np.maximum(t - end, 0.0) * y[-1]


def sample(
    y: np.ndarray, fast_s: float, t: np.ndarray, *, delay_s: float, window_s: float
) -> np.ndarray:
    """The zero-order-hold signal y (period fast_s) seen at times t, delay_s late: the mean over
    (t - delay - window, t - delay] if window_s > 0, else the value held at t - delay."""
    shift = round(delay_s / fast_s) * fast_s
    tt = np.asarray(t, dtype=float) - shift
    if window_s > 0.0:
        return (_integral(y, fast_s, tt) - _integral(y, fast_s, tt - window_s)) / window_s
    index = np.ceil(tt / fast_s - 1e-9).astype(int) - 1
    return y[np.clip(index, 0, len(y) - 1)]


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """x rounded to whole steps (step 0: unchanged)."""
    return np.round(x / step) * step if step > 0.0 else np.asarray(x, dtype=float)
