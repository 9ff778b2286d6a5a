"""The shadow twin of a machine, in-process: every simulated axis shadowed beside a stand-in.

Per axis, the stand-in (feed_twin.shadow.standin: the axis model with its `shadow.standin`
hidden effects and unmodelled dynamics, the "real machine") follows the NC command of the
machine's program, and the shadow twin (feed_twin.shadow.twin.ShadowTwin: the nominal model of
the same axis) runs beside it on the same command; residuals (following-error and effort
deviation) and health verdicts come out per axis. The program is fed in steps of the health
evaluation period, so the stand-in's `friction_steps` (a guide that wears at a given time)
change its truth from the step they fall in. Each axis uses its own `shadow:` section (the
included axis file's, or the machine entry's own).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.gcode.planner import plan_program
from feed_twin.io.config import ConfigError
from feed_twin.machine.config import MachineConfig
from feed_twin.shadow.config import ShadowConfig, load_shadow_config
from feed_twin.shadow.health import LEVEL_NAMES, OK, Verdict
from feed_twin.shadow.standin import StandIn
from feed_twin.shadow.twin import ResidualBlock, ShadowTwin
from feed_twin.sim.program import with_settle


@dataclass(frozen=True, kw_only=True)
class AxisShadow:
    """What the shadow twin of one axis found."""

    axis: str
    samples: ResidualBlock
    verdicts: tuple[Verdict, ...]
    effort_unit: str

    def summary(self) -> dict[str, Any]:  # JSON values of several types
        ok = np.isfinite(self.samples.x_twin_m)
        fe = self.samples.fe_dev_m[ok]
        effort = self.samples.effort_dev[ok]
        worst = max((v.level for v in self.verdicts), default=OK)
        warned = [v for v in self.verdicts if v.level != OK]
        named = [v for v in warned if v.effect]
        return {
            "fe_dev_rms_m": float(np.sqrt(np.mean(fe**2))) if len(fe) else float("nan"),
            "effort_dev_rms": float(np.sqrt(np.nanmean(effort**2))) if len(effort) else 0.0,
            "effort_unit": self.effort_unit,
            "health": LEVEL_NAMES[worst],
            "first_warning_s": warned[0].t_s if warned else None,
            "effect": named[-1].effect if named else "",
            "message": named[-1].message if named else "",
        }


def axis_shadow_config(machine: MachineConfig, axis: str) -> ShadowConfig:
    config = machine.axes[axis]
    if config.shadow is None:
        raise ConfigError(
            f"{config.source}: axis {axis}: no shadow: section (the shadow twin's limits and "
            "its stand-in)"
        )
    return load_shadow_config({"shadow": config.shadow}, source=config.source)


def shadow_machine(
    machine: MachineConfig, program: str | Path, *, settle_s: float = 0.2
) -> dict[str, AxisShadow]:
    """Shadow every simulated axis of the machine on `program` (module docstring)."""
    nc = machine.nc
    configs = {axis: axis_shadow_config(machine, axis) for axis in machine.axes}
    for axis, cfg in configs.items():
        if abs(cfg.sample_period_s - nc.interpolation_period_s) > 1e-12:
            raise ConfigError(
                f"{machine.axes[axis].source}: shadow.sample_period_s = {cfg.sample_period_s!r}: "
                f"must equal nc.interpolation_period_s = {nc.interpolation_period_s!r}"
            )
    traj = with_settle(plan_program(program, nc), settle_s)
    return {axis: _shadow_axis(machine, axis, configs[axis], traj) for axis in machine.axes}


def _shadow_axis(machine: MachineConfig, axis: str, cfg: ShadowConfig, traj) -> AxisShadow:
    config = machine.axes[axis]
    doc = ModelDoc(data=dict(config.raw), source=config.source)
    twin = Twin.compile(doc)
    x, v, a = traj.axis(axis)
    t = traj.t_s
    standin = StandIn.from_config(
        doc, cfg.standin, sample_period_s=cfg.sample_period_s, x0_m=float(x[0])
    )
    nc_axis = machine.nc.axes[machine.nc.axis_index(axis)]
    shadow = ShadowTwin(
        twin,
        cfg,
        command_velocity=True,
        travel_m=nc_axis.travel_max_m - nc_axis.travel_min_m,
    )
    nominal = {name: standin.parameter(name) for name in standin.friction_parameters()}
    steps = sorted((s.at_s, s.scale) for s in cfg.standin.friction_steps)
    chunk = max(1, round(cfg.evaluate_period_s / cfg.sample_period_s))
    blocks: list[ResidualBlock] = []
    verdicts: list[Verdict] = []
    for k0 in range(0, len(t), chunk):
        k1 = min(len(t), k0 + chunk)
        while steps and steps[0][0] <= t[k0] - t[0]:
            _, scale = steps.pop(0)
            for name, value in nominal.items():
                standin.set_parameter(name, value * scale)
        x_meas, effort = standin.step(x[k0:k1], v[k0:k1], a[k0:k1])
        shadow.push_commands(t[k0:k1], x[k0:k1], v[k0:k1])
        shadow.push_measured_many(t[k0:k1], x_meas, effort)
        block = shadow.process(final=k1 == len(t))
        verdicts += shadow.new_verdicts
        if block is not None:
            blocks.append(block)
    return AxisShadow(
        axis=axis,
        samples=ResidualBlock.concat(blocks),
        verdicts=tuple(verdicts),
        effort_unit=twin.effort_unit,
    )
