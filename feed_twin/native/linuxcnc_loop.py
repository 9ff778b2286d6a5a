"""LinuxCNC's own loop closed on the twin: the HAL component in the servo thread of a whole
LinuxCNC machine (feed_twin.linuxcnc), in place of the simulated joint of the twin's axis.

The machine files are feed_twin.linuxcnc.machine's for the axis config; `twin_machine` edits
their HAL: `loadrt feed_twin_axis`, its function added to the servo thread before the sampler
(which stays last), the joint's motor-pos-cmd, vel-cmd and acc-cmd into the component and its
`pos-fb` into the joint's motor-pos-fb. The simulated joint (PID, lowpass drive, integrator)
keeps running on the same command, its feedback no longer used. `compare_runs` runs a program
on the plain machine and on the one with the twin and returns both traces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feed_twin.native.hal import MODULE

_JOINTS = "xyz"


@dataclass(frozen=True)
class LoopFigures:
    """Following error [m] and the periods lost of one run of the program."""

    f_error_max_m: float
    f_error_rms_m: float
    samples_lost: int
    overruns: int
    periods: int


@dataclass(frozen=True)
class PidGains:
    """LinuxCNC's pid for a q-current output [A] from a position error [mm]."""

    p: float  # [A/mm]
    d: float  # [A s/mm]
    ff2: float  # [A s^2/mm] acceleration feed-forward
    max_output: float  # [A]


def pid_gains(cascade, bandwidth_hz: float = 25.0, zeta: float = 0.7) -> PidGains:
    """PD gains that place the poles of the rigid axis (x'' = b i) at `bandwidth_hz` with
    damping `zeta`; b from the drive's acceleration feed-forward gain (A per m/s^2, the inertia
    over the torque constant through the lead), FF2 its inverse feed-forward."""
    from feed_twin.control import layout

    per_m_s2 = float(cascade.params[layout.P_ACC_FF_GAIN])  # [A per m/s^2]
    b = 1000.0 / per_m_s2  # [mm/s^2 per A]
    w = 2.0 * math.pi * bandwidth_hz
    return PidGains(
        p=w * w / b,
        d=2.0 * zeta * w / b,
        ff2=per_m_s2 / 1000.0,
        max_output=float(cascade.params[layout.P_EFFORT_LIMIT]),
    )


def twin_hal(hal_text: str, axis_name: str, start_mm: float, *, pid: PidGains | None = None) -> str:
    """The machine's HAL text with the twin closing the loop of joint `axis_name` (X, Y or Z):
    at a position boundary (`pid` None) the joint's commands go to the twin's drive; at a
    torque boundary LinuxCNC's pid closes the position loop and its output is the twin's
    q-current setpoint."""
    j = _JOINTS.index(axis_name.lower())
    name = _JOINTS[j]
    feedback = f"net {name}-pos-fb scale.{name}.out => pid.{name}.feedback joint.{j}.motor-pos-fb"
    sampler = "addf sampler.0 servo-thread"
    for needed in (feedback, sampler):
        if needed not in hal_text:
            raise ValueError(f"machine.hal: no line {needed!r} to put the twin in")
    common = [
        f"net {name}-enable => feed-twin-axis.enable",
        f"setp feed-twin-axis.start-pos {start_mm!r}",
    ]
    if pid is None:
        lines = [
            f"net {name}-pos-fb scale.{name}.out => pid.{name}.feedback",
            f"net {name}-pos-cmd => feed-twin-axis.pos-cmd",
            f"net {name}-vel-cmd => feed-twin-axis.vel-cmd",
            f"net {name}-acc-cmd => feed-twin-axis.acc-cmd",
            *common,
            f"net {name}-twin-fb feed-twin-axis.pos-fb => joint.{j}.motor-pos-fb",
        ]
    else:
        lines = [
            f"net {name}-pos-fb scale.{name}.out",
            f"net {name}-output => feed-twin-axis.current-cmd",
            *common,
            f"setp pid.{name}.Pgain {pid.p!r}",
            f"setp pid.{name}.Dgain {pid.d!r}",
            f"setp pid.{name}.FF1 0",
            f"setp pid.{name}.FF2 {pid.ff2!r}",
            f"setp pid.{name}.maxoutput {pid.max_output!r}",
            f"net {name}-twin-fb feed-twin-axis.pos-fb => pid.{name}.feedback "
            f"joint.{j}.motor-pos-fb",
        ]
    text = hal_text.replace(feedback, "\n".join(lines))
    return text.replace(sampler, f"addf feed-twin-axis servo-thread\n{sampler}", 1).replace(
        "loadrt feedtwin_clock", f"loadrt feedtwin_clock\nloadrt {MODULE}", 1
    )


def twin_machine(config: str | Path, directory: Path, *, boundary: str = "position"):
    """Machine files of `config` in `directory` with the twin in the loop at `boundary`
    (position: LinuxCNC's commands into the twin's drive; torque: LinuxCNC's pid output as its
    current setpoint; build the component with the same --mode); (nc, servo)."""
    from feed_twin.control.layout import build_cascade
    from feed_twin.linuxcnc.machine import machine_for_config, write_machine
    from feed_twin.sim.config import load_axis_config

    if boundary not in ("position", "torque"):
        raise ValueError(f"boundary = {boundary!r}: position or torque")
    nc, servo = machine_for_config(str(config))
    write_machine(directory, nc, servo)
    hal = directory / "machine.hal"
    index = [a.name for a in nc.axes].index(nc.twin_axis)
    start_mm = nc.start_position_m[index] * 1000.0
    pid = None
    if boundary == "torque":
        pid = pid_gains(build_cascade(load_axis_config(config).controller))
    hal.write_text(twin_hal(hal.read_text(), nc.twin_axis, start_mm, pid=pid))
    return nc, servo


def run(program: Path, nc, servo, machine: Path | None = None):
    """feed_twin.linuxcnc's run_program (on `machine`'s files when given), once more when
    LinuxCNC did not start: rtapi_app sometimes fails to come up right after another session
    exited (seen about once in a dozen back-to-back starts, also by the runner's own benchmark)."""
    from feed_twin.linuxcnc.host import LinuxcncError
    from feed_twin.linuxcnc.runner import RunOptions, run_program

    options = RunOptions() if machine is None else RunOptions(machine_dir=machine)
    try:
        return run_program(program, nc=nc, servo=servo, options=options)
    except LinuxcncError as exc:
        if "did not start" not in str(exc):
            raise
        return run_program(program, nc=nc, servo=servo, options=options)


def figures(result, axis_index: int) -> LoopFigures:
    full = result.trace
    trace = full.cut(full.program_span())
    fe = trace.f_error_m[:, axis_index]
    return LoopFigures(
        f_error_max_m=float(np.abs(fe).max()),
        f_error_rms_m=float(np.sqrt(np.mean(fe**2))),
        samples_lost=int(full.samples_lost),
        overruns=int(result.overruns),
        periods=len(fe),
    )


def compare_runs(
    program: Path, config: str | Path, workdir: Path, *, boundary: str = "position"
) -> dict[str, LoopFigures]:
    """The program on LinuxCNC's simulated joint and with the twin in the servo loop (the
    installed component must be built for `boundary`)."""
    from feed_twin.linuxcnc.machine import machine_for_config

    nc, servo = machine_for_config(str(config))
    index = [a.name for a in nc.axes].index(nc.twin_axis)
    plain = run(program, nc, servo)
    machine = workdir / "machine_twin"
    machine.mkdir(parents=True, exist_ok=True)
    nc, servo = twin_machine(config, machine, boundary=boundary)
    twin = run(program, nc, servo, machine)
    return {"simulated_joint": figures(plain, index), "twin": figures(twin, index)}
