"""A program on the machine twin in-process: feed_twin.sim.program.simulate_program runs every
simulated axis on the NC's plan, and the tool point is measured against the programmed path.

    machine = load_machine_config("config/machine_default.yaml")
    run = simulate_machine(machine, "part.ngc")
    run.summary()["contour_error_max_m"]

Each axis plant names its table `table` with the machine coordinate `table.s` (the axis files'
convention: the ROS node set reads the same signal).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.gcode.geometry import programmed_path
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.contour import ContourError, contour_error
from feed_twin.nodeset.config import StateSignals
from feed_twin.sim.config import build_engine
from feed_twin.sim.program import TABLE_POSITION, ProgramRun, simulate_program

# what the drive reports beside the plant's truth (AxisState's setpoint and following error)
DRIVE_SIGNALS = ("out.pos_ref_m", "out.following_error_m")


@dataclass(frozen=True, kw_only=True)
class MachineRun(ProgramRun):
    """A program run on the machine with its contour error."""

    contour: ContourError
    state_signals: dict[str, StateSignals]  # axis -> the engine signals behind its AxisState

    def summary(self) -> dict[str, Any]:  # JSON values of several types
        out: dict[str, Any] = dict(self.contour.summary())
        out["following_error_max_m"] = {
            a.lower(): float(np.max(np.abs(self.following_error(a)))) for a in self.simulated
        }
        out["simulated_s"] = float(self.t_s[-1]) if len(self.t_s) else 0.0
        out["axes"] = [a.lower() for a in self.simulated]
        return out


def axis_state_signals(machine: MachineConfig, axis: str) -> StateSignals:
    """The engine signals behind axis `axis`'s AxisState fields (from its plant's components)."""
    config = machine.axes[axis]
    period = machine.nc.interpolation_period_s
    known = build_engine(config, output_period_s=period).all_names
    try:
        return StateSignals().resolve(config.plant, known)
    except ValueError as exc:
        raise ConfigError(f"{config.source}: axis {axis}: {exc}") from None


def simulate_machine(
    machine: MachineConfig,
    program: str | Path,
    *,
    settle_s: float = 0.2,
    preroll_s: float = 0.5,
    on_progress: Callable[[float], None] | None = None,
) -> MachineRun:
    """Plan `program` on the machine's NC, run every simulated axis, measure the contour;
    `on_progress` hears the simulated time [s] reached as the axes advance."""
    states = {axis: axis_state_signals(machine, axis) for axis in machine.axes}
    reported = dict.fromkeys(n for names in states.values() for n in names.names())
    record = (TABLE_POSITION, *DRIVE_SIGNALS, *reported, "table.a")
    run = simulate_program(
        machine, program, settle_s=settle_s, preroll_s=preroll_s, record=record,
        on_progress=on_progress,
    )  # fmt: skip
    contour = contour_error(
        run.t_s,
        run.line,
        run.actual,
        run.command,
        run.command_vel,
        programmed_path(program, machine.nc),
        n_linear=len(machine.nc.axes),
    )
    fields = {f.name: getattr(run, f.name) for f in dataclasses.fields(run)}
    return MachineRun(**fields, contour=contour, state_signals=states)
