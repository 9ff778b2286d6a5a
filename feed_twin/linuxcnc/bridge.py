"""From LinuxCNC's servo periods to the twin's samples: stamps, the pairing, counts, latency.

Pure (no rclpy); the ROS 2 node feed_twin/ros/linuxcnc_node.py publishes what `ServoBridge`
makes of each batch of rows:

- time: the stamp of servo period k is (k - k0) * period, k0 the first period with a program
  line on the motion controller (the program's first motion); periods before it are counted but
  not published. The wall clock never enters a stamp.
- command (AxisCommand of the twin's joint): LinuxCNC's commanded position, velocity and
  acceleration of period k, stamped k, with its program line (-1 outside a program's motion).
- measured (the twin's machine side): LinuxCNC reads in period k the feedback its servo loop
  produced in period k - 1, so row k's feedback is published stamped k - 1. The shadow twin's
  following error x_cmd(k - 1) - x_meas(k - 1) is then LinuxCNC's own f-error of row k.
- counts: rows received, rows missing (gaps in the servo thread's tick counter), published.
- the servo thread's own timing: start lateness and interval jitter of every received period
  (feed_twin.linuxcnc.period_timing), reported as `servo_*`.
- latency (CLOCK_MONOTONIC, the servo thread's clock too): the bridge latency is servo tick ->
  the period's samples handed to DDS (`mark_published`), which the twin receives one DDS hop
  later (half a round trip between processes, 0.1-0.2 ms on this machine); the start of each
  published period is also kept until the twin's output for that stamp comes back
  (`twin_output`): servo tick -> twin output, the twin's own work and the hop back included.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from feed_twin.linuxcnc.period_timing import period_timing
from feed_twin.linuxcnc.samples import JOINT_LETTERS, ROW_HEADER, SampleLayout, rows_to_trace

NS_PER_S = 1_000_000_000
PENDING_LIMIT = 120_000  # stamps awaiting the twin's output (2 min at 1 kHz): bounded memory
LATENCY_PARTS = ("servo_to_reader", "reader_to_bridge", "bridge_to_published")


@dataclass(frozen=True, kw_only=True)
class BridgeBatch:
    """What to publish for a batch of rows (arrays of one length unless said otherwise)."""

    stamp_ns: np.ndarray  # int64, per published period
    tick: np.ndarray  # int64, servo period index (LinuxCNC's)
    tick_time_s: np.ndarray  # CLOCK_MONOTONIC period start [s]
    line: np.ndarray  # int64, program line, -1 outside a program's motion
    pos_cmd_m: np.ndarray  # (n, 3) [m]
    vel_cmd_m_s: np.ndarray  # (n, 3) [m/s]
    acc_cmd_m_s2: np.ndarray  # (n, 3) [m/s^2]
    pos_fb_m: np.ndarray  # (n, 3) [m]
    f_error_m: np.ndarray  # (n, 3) [m]
    pid_output_m_s: np.ndarray  # (n, 3) [m/s]
    measured_stamp_ns: np.ndarray  # int64, stamps of the measured samples (may be one shorter)
    measured_pos_m: np.ndarray  # [m] the twin joint's feedback for those stamps
    receive_time_s: np.ndarray  # CLOCK_MONOTONIC when LinuxCNC's reader took each period [s]
    taken_s: float  # CLOCK_MONOTONIC when the bridge took the batch [s]

    def __len__(self) -> int:
        return int(self.stamp_ns.size)


class ServoBridge:
    """Turns row batches into stamped samples of joint `joint` (module docstring)."""

    def __init__(self, layout: SampleLayout, *, period_s: float, joint: int) -> None:
        if joint not in range(len(JOINT_LETTERS)):
            raise ValueError(f"joint = {joint!r}: must be 0, 1 or 2 (X, Y, Z)")
        self.layout = layout
        self.period_s = period_s
        self.joint = joint
        self.k0: int | None = None  # tick of the program's first motion
        self.received = 0
        self.lost = 0
        self.published = 0
        self._last_tick: int | None = None
        self._pending: OrderedDict[int, float] = OrderedDict()  # stamp_ns -> tick time [s]
        self.publish_latency_s: list[np.ndarray] = []
        self._latency_parts: dict[str, list[np.ndarray]] = {part: [] for part in LATENCY_PARTS}
        self._ticks: list[np.ndarray] = []  # every received period's tick and start time
        self._starts_s: list[np.ndarray] = []
        self.twin_latency_s: list[float] = []

    def take(self, rows: np.ndarray, *, now_s: float) -> BridgeBatch | None:
        """The samples of `rows` to publish (None before the program's first motion)."""
        if rows.size == 0:
            return None
        ticks = rows[:, len(ROW_HEADER) + self.layout.index("tick")].astype(np.int64)
        self.received += len(ticks)
        previous = self._last_tick if self._last_tick is not None else int(ticks[0]) - 1
        self.lost += int(ticks[-1] - previous) - len(ticks)
        self._last_tick = int(ticks[-1])
        trace = rows_to_trace(rows, self.layout, period_s=self.period_s)
        self._ticks.append(ticks)
        self._starts_s.append(trace.tick_time_s)
        if self.k0 is None:
            running = np.flatnonzero(trace.program_line != 0)
            if running.size == 0:
                return None
            self.k0 = int(ticks[running[0]])
        keep = ticks >= self.k0
        k = ticks[keep]
        stamp = (k - self.k0) * round(self.period_s * NS_PER_S)
        fb = trace.pos_fb_m[keep]
        measured = stamp > 0  # row k's feedback belongs to period k - 1
        batch = BridgeBatch(
            stamp_ns=stamp,
            tick=k,
            tick_time_s=trace.tick_time_s[keep],
            line=np.where(trace.program_line[keep] > 0, trace.program_line[keep], -1),
            pos_cmd_m=trace.pos_cmd_m[keep],
            vel_cmd_m_s=trace.vel_cmd_m_s[keep],
            acc_cmd_m_s2=trace.acc_cmd_m_s2[keep],
            pos_fb_m=fb,
            f_error_m=trace.f_error_m[keep],
            pid_output_m_s=trace.pid_output_m_s[keep],
            measured_stamp_ns=stamp[measured] - round(self.period_s * NS_PER_S),
            measured_pos_m=fb[measured, self.joint],
            receive_time_s=trace.receive_time_s[keep],
            taken_s=now_s,
        )
        self.published += len(batch)
        for s, t in zip(batch.stamp_ns.tolist(), batch.tick_time_s.tolist(), strict=True):
            self._pending[s] = t
        while len(self._pending) > PENDING_LIMIT:
            self._pending.popitem(last=False)
        return batch

    def twin_output(self, stamp_ns: int, *, now_s: float) -> None:
        """The twin's output for `stamp_ns` arrived at `now_s` (CLOCK_MONOTONIC)."""
        tick_time = self._pending.pop(stamp_ns, None)
        if tick_time is not None:
            self.twin_latency_s.append(now_s - tick_time)

    def mark_published(self, batch: BridgeBatch, start: int, stop: int, *, now_s: float) -> None:
        """Periods `start` to `stop` of `batch` were handed to DDS by `now_s` (CLOCK_MONOTONIC).
        Their latency in three parts: servo tick -> LinuxCNC's reader (the display program
        draining the sampler FIFO), reader -> the bridge's batch (the pipe and the bridge's
        loop), the bridge's batch -> published (packing, and the window to the twin)."""
        tick, received = batch.tick_time_s[start:stop], batch.receive_time_s[start:stop]
        self.publish_latency_s.append(now_s - tick)
        self._latency_parts["servo_to_reader"].append(received - tick)
        self._latency_parts["reader_to_bridge"].append(batch.taken_s - received)
        waited = np.full(stop - start, now_s - batch.taken_s)
        self._latency_parts["bridge_to_published"].append(waited)

    def report(self) -> dict[str, object]:
        publish = (
            np.concatenate(self.publish_latency_s) * 1e3 if self.publish_latency_s else np.empty(0)
        )
        twin = np.asarray(self.twin_latency_s) * 1e3
        timing = {}
        if self.received >= 2:
            timing = period_timing(
                np.concatenate(self._ticks), np.concatenate(self._starts_s), period_s=self.period_s
            ).as_dict()
        return {
            "samples_received": self.received,
            "samples_lost": self.lost,
            "samples_published": self.published,
            # periods of the program, first motion to the last period received (gaps included)
            "program_periods": 0
            if self.k0 is None or self._last_tick is None
            else self._last_tick - self.k0 + 1,
            **_percentiles("bridge_latency", publish),
            **_percentiles("twin_output_latency", twin),
            # where the bridge latency goes (mark_published), p99 of each part [ms]
            "bridge_latency_parts_p99_ms": {
                part: float(np.percentile(np.concatenate(values), 99)) * 1e3 if values else None
                for part, values in self._latency_parts.items()
            },
            **{f"servo_{key}": value for key, value in timing.items()},
        }


def _percentiles(name: str, ms: np.ndarray) -> dict[str, float | int | None]:
    return {
        f"{name}_p50_ms": float(np.percentile(ms, 50)) if ms.size else None,
        f"{name}_p99_ms": float(np.percentile(ms, 99)) if ms.size else None,
        f"{name}_max_ms": float(ms.max()) if ms.size else None,
        f"{name}_count": int(ms.size),
    }
