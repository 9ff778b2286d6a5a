"""Virtual commissioning: LinuxCNC's servo loop closed over the twin's axis instead of HAL's plant.

LinuxCNC runs the program with the twin's joint wired as a fieldbus drive would be
(feed_twin.linuxcnc.machine, `twin_joint`): its PID output (a velocity command, FF1 + P) leaves
through the sampler, and the position feedback comes back through a HAL streamer. Here, for
each servo period k, in order:

    u_k = PID output of period k                      [m/s, table]
    the twin's drive (DriveHost at the velocity boundary, CiA 402 CSV: velocity and current
    loops, inverter, motor, screw, table) holds u_k for one period; the scale position it
    latched at the start of that period, x(t_k), goes back to LinuxCNC
    LinuxCNC reads x(t_k) as motor-pos-fb in period k + 1

so LinuxCNC sees the twin's axis one period late, as through an EtherCAT drive that latches its
feedback at SYNC0 and applies the master's setpoint at the next cycle. Nothing is paced: the
twin answers as soon as a period's row arrives. LinuxCNC does not wait for it (it cannot be
stepped from outside), so a value that is not in the streamer when its period runs is a missed
period: LinuxCNC reuses the previous feedback (the streamer's underrun) and the late value is
dropped (`_display.py`). Without a PREEMPT_RT kernel and with the twin in another process that
happens; `missed_periods` counts it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feed_twin.core import signals as sig
from feed_twin.linuxcnc.machine import machine_for_config
from feed_twin.linuxcnc.period_timing import PeriodTiming
from feed_twin.linuxcnc.runner import LinuxcncRun, RunOptions
from feed_twin.linuxcnc.samples import JOINT_LETTERS, ROW_HEADER, ServoTrace, sample_layout

M_PER_MM = 1e-3
FERROR_SCALE = 10.0  # LinuxCNC's following-error limits in commissioning, times the config's


@dataclass(frozen=True, kw_only=True)
class CommissioningResult:
    trace: ServoTrace  # LinuxCNC's record; the twin joint's feedback is the twin's scale
    joint: int  # the twin's joint (0, 1, 2 = X, Y, Z)
    twin_scale_m: np.ndarray  # [m] per row: the scale position sent back for that row's period
    missed_periods: int  # periods of the program in which LinuxCNC found no twin feedback
    program_periods: int  # periods of the program (for the share missed)

    def period_timing(self) -> PeriodTiming:
        """The servo thread's start lateness and jitter over the program (its own clock): a
        period that started late left the twin less time to answer."""
        return self.trace.cut(self.trace.program_span()).period_timing()

    @property
    def following_error_max_m(self) -> float:
        """[m] LinuxCNC's largest following error of the twin joint over the program."""
        return float(np.max(np.abs(self.trace.f_error_m[self.trace.program_span(), self.joint])))


def run_virtual_commissioning(
    program: str | Path,
    config: str | Path,
    *,
    options: RunOptions | None = None,
    say: Callable[[str], None] = print,
) -> CommissioningResult:
    """Run `program` on LinuxCNC with the twin of `config` as its twin axis (module docstring)."""
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.nodeset.drive_host import build_drive_host

    nc, servo = machine_for_config(config)
    # Missed periods freeze LinuxCNC's feedback; a burst of them on a loaded host (a 0.2 s
    # stall at 5 mm/s is 1 mm) would stop the machine at the axis config's limits: the
    # commissioning run shows that as following error instead, up to FERROR_SCALE times them.
    servo = dataclasses.replace(
        servo,
        ferror_m=FERROR_SCALE * servo.ferror_m,
        min_ferror_m=FERROR_SCALE * servo.min_ferror_m,
    )
    joint = nc.axis_index(nc.twin_axis)
    ros = dataclasses.replace(load_node_set_config(config), boundary="velocity")
    if abs(ros.exchange_period_s - servo.servo_period_s) > 1e-12:
        raise ValueError(
            f"{config}: ros.exchange_period_s = {ros.exchange_period_s!r}: the twin exchanges "
            f"once per LinuxCNC servo period ({servo.servo_period_s!r} s)"
        )
    host = build_drive_host(config, ros)
    host.warm_up()
    options = dataclasses.replace(options or RunOptions(), twin_joint=joint)
    sent: list[np.ndarray] = []
    output = len(ROW_HEADER) + sample_layout().index(f"{JOINT_LETTERS[joint]}.pid_output")

    def answer(rows: np.ndarray) -> np.ndarray:
        x = _twin_answers(host, rows[:, output] * M_PER_MM)
        sent.append(x)
        return x

    with LinuxcncRun(program, nc=nc, servo=servo, options=options, twin=answer, say=say) as run:
        run.wait_end()
    trace = run.trace()
    span = trace.program_span()
    late = {e["event"]: (e.get("twin") or [0, 0])[1] for e in run.state.events}
    return CommissioningResult(
        trace=trace,
        joint=joint,
        twin_scale_m=np.concatenate(sent) if sent else np.empty(0),
        missed_periods=int(late["program_done"] - late["started"]),
        program_periods=span.stop - span.start,
    )


def _twin_answers(host, velocity_m_s: np.ndarray) -> np.ndarray:
    """The scale positions latched at the start of each period, each period driven at its
    velocity command (CiA 402 cyclic synchronous velocity)."""
    from feed_twin.nodeset.drive_host import MEAS_RECORD
    from feed_twin.nodeset.wire import MODE_CSV, DriveSetpoint

    scale = host.engine.record_names.index(MEAS_RECORD[sig.MEAS_X_SCALE_M])
    x = np.empty(len(velocity_m_s))
    for i, v in enumerate(velocity_m_s.tolist()):
        _, row = host.advance(
            DriveSetpoint(t_ns=host.t_ns, mode=MODE_CSV, enable=True, velocity_m_s=v)
        )
        x[i] = row[scale]
    return x
