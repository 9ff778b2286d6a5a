"""The timing report of a node that steps a simulation: how fast, and how late in real time.

steps * period_s simulated over wall_s seconds of wall time: realtime_factor = sim / wall.
In real-time mode every step k is due at wall t0 + k * period_s; lateness is how much after
that it started, reported as p50/p99/max in ms, with the steps counted as missed.

In real time the sim announces its pace on `run_state` (`realtime_announcement`) with the
SCHED_FIFO priority of the exchange. The controller takes that priority; the G-code node takes
the one below (`setpoint_priority`): its setpoints are due `ros.lookahead` periods ahead of the
exchange, and under normal scheduling on a loaded host (load 10-20 on 2 cores) it waited
longer than that for a CPU, its lead fell below zero and the drive tripped on its following
error (benchmarks/realtime_faults.py). One below, it runs before every normal process and
never ahead of the exchange.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

REALTIME_WORD = "realtime"  # the first word of the sim's real-time announcement


def realtime_announcement(priority: int) -> str:
    """The sim's `run_state` text when it paces by the wall clock: the SCHED_FIFO priority of
    the exchange (0: normal scheduling)."""
    return f"{REALTIME_WORD} priority {priority}"


def announced_priority(text: str) -> int | None:
    """The exchange's SCHED_FIFO priority of a real-time announcement (0: normal scheduling);
    None when `text` is not one."""
    word, _, priority = text.partition(" priority ")
    if word != REALTIME_WORD or not priority.isdigit():
        return None
    return int(priority)


def setpoint_priority(exchange_priority: int) -> int:
    """The G-code node's SCHED_FIFO priority under an exchange at `exchange_priority`: one
    below it, at least 1 (module docstring); 0 (normal) beside a normal exchange."""
    return max(exchange_priority - 1, 1) if exchange_priority > 0 else 0


def pacing_report(
    *,
    steps: int,
    period_s: float,
    wall_s: float,
    lateness_s: Sequence[float] | None = None,
    missed_steps: int | None = None,
) -> dict[str, float | int | None]:
    """steps, sim_time_s, wall_time_s, realtime_factor (None for no wall time); with
    `lateness_s` (real-time mode) also lateness_p50/p99/max_ms (NaN without samples) and
    missed_steps (given, or the steps later than one period)."""
    sim_s = steps * period_s
    report: dict[str, float | int | None] = {
        "steps": steps,
        "sim_time_s": sim_s,
        "wall_time_s": wall_s,
        "realtime_factor": sim_s / wall_s if wall_s > 0 else None,
    }
    if lateness_s is not None:
        late = np.asarray(lateness_s, dtype=float) * 1e3
        if missed_steps is None:
            missed_steps = int(np.count_nonzero(late > period_s * 1e3))
        report.update(
            lateness_p50_ms=float(np.percentile(late, 50)) if late.size else math.nan,
            lateness_p99_ms=float(np.percentile(late, 99)) if late.size else math.nan,
            lateness_max_ms=float(late.max()) if late.size else math.nan,
            missed_steps=missed_steps,
        )
    return report
