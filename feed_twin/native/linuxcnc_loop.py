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


def twin_hal(hal_text: str, axis_name: str, start_mm: float) -> str:
    """The machine's HAL text with the twin closing the loop of joint `axis_name` (X, Y or Z)."""
    j = _JOINTS.index(axis_name.lower())
    name = _JOINTS[j]
    feedback = f"net {name}-pos-fb scale.{name}.out => pid.{name}.feedback joint.{j}.motor-pos-fb"
    sampler = "addf sampler.0 servo-thread"
    for needed in (feedback, sampler):
        if needed not in hal_text:
            raise ValueError(f"machine.hal: no line {needed!r} to put the twin in")
    text = hal_text.replace(
        feedback,
        "\n".join(
            [
                f"net {name}-pos-fb scale.{name}.out => pid.{name}.feedback",
                f"net {name}-pos-cmd => feed-twin-axis.pos-cmd",
                f"net {name}-vel-cmd => feed-twin-axis.vel-cmd",
                f"net {name}-acc-cmd => feed-twin-axis.acc-cmd",
                f"net {name}-enable => feed-twin-axis.enable",
                f"setp feed-twin-axis.start-pos {start_mm!r}",
                f"net {name}-twin-fb feed-twin-axis.pos-fb => joint.{j}.motor-pos-fb",
            ]
        ),
    )
    return text.replace(sampler, f"addf feed-twin-axis servo-thread\n{sampler}", 1).replace(
        "loadrt feedtwin_clock", f"loadrt feedtwin_clock\nloadrt {MODULE}", 1
    )


def twin_machine(config: str | Path, directory: Path):
    """Machine files of `config` in `directory` with the twin in the loop; (nc, servo)."""
    from feed_twin.linuxcnc.machine import machine_for_config, write_machine

    nc, servo = machine_for_config(str(config))
    write_machine(directory, nc, servo)
    hal = directory / "machine.hal"
    index = [a.name for a in nc.axes].index(nc.twin_axis)
    start_mm = nc.start_position_m[index] * 1000.0
    hal.write_text(twin_hal(hal.read_text(), nc.twin_axis, start_mm))
    return nc, servo


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


def compare_runs(program: Path, config: str | Path, workdir: Path) -> dict[str, LoopFigures]:
    """The program on LinuxCNC's simulated joint and with the twin in the servo loop."""
    from feed_twin.linuxcnc.machine import machine_for_config
    from feed_twin.linuxcnc.runner import RunOptions, run_program

    nc, servo = machine_for_config(str(config))
    index = [a.name for a in nc.axes].index(nc.twin_axis)
    plain = run_program(program, nc=nc, servo=servo)
    machine = workdir / "machine_twin"
    machine.mkdir(parents=True, exist_ok=True)
    nc, servo = twin_machine(config, machine)
    twin = run_program(program, nc=nc, servo=servo, options=RunOptions(machine_dir=machine))
    return {"simulated_joint": figures(plain, index), "twin": figures(twin, index)}
