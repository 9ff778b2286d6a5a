"""The shadow twin of a machine, in-process: every simulated axis shadowed beside a stand-in.

Per axis, the stand-in (feed_twin.shadow.standin: the axis model with its `shadow.standin`
hidden effects and unmodelled dynamics, the "real machine") follows the NC command of the
machine's program, and the shadow twin (feed_twin.shadow.twin.ShadowTwin: the nominal model of
the same axis) runs beside it on the same command; residuals (following-error and effort
deviation) and health verdicts come out per axis. The program is fed in steps of the health
evaluation period; the stand-in's `friction_steps` (a guide that wears at a given time) change
its truth from the first sample at or after their time, as the stand-in node plays them. Each
axis uses its own `shadow:` section (the included axis file's, or the machine entry's own).

The same machine shadow as ROS nodes (a stand-in and a twin node per axis): feed_twin.machine.
shadow_nodes; its per-axis figures come from the bag through `axis_figures`, as here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.core.config import ConfigError
from feed_twin.gcode.planner import plan_program
from feed_twin.machine.config import MachineConfig
from feed_twin.nodeset.run_report import shown
from feed_twin.shadow.config import ShadowConfig, load_shadow_config
from feed_twin.shadow.health import LEVEL_NAMES, OK, Verdict
from feed_twin.shadow.standin import EFFORT_SAMPLE, StandIn
from feed_twin.shadow.twin import ResidualBlock, ShadowTwin
from feed_twin.sim.program import with_settle

STEP_TOLERANCE_S = 1e-12  # [s] a friction step at_s acts from the sample at at_s (rounding)


@dataclass(frozen=True, kw_only=True)
class AxisShadow:
    """What the shadow twin of one axis found."""

    axis: str
    samples: ResidualBlock
    verdicts: tuple[Verdict, ...]
    effort_unit: str

    def summary(self) -> dict[str, Any]:  # JSON values of several types
        v = self.verdicts
        return axis_figures(
            fe_dev_m=self.samples.fe_dev_m,
            effort_dev=self.samples.effort_dev,
            twin_ok=np.isfinite(self.samples.x_twin_m),
            verdict_t_s=np.array([x.t_s for x in v]),
            verdict_level=np.array([x.level for x in v], dtype=np.int64),
            verdict_effect=[x.effect for x in v],
            verdict_message=[x.message for x in v],
            effort_unit=self.effort_unit,
        )


def axis_figures(
    *,
    fe_dev_m: np.ndarray,
    effort_dev: np.ndarray,
    twin_ok: np.ndarray,
    verdict_t_s: np.ndarray,
    verdict_level: np.ndarray,
    verdict_effect: list[str],
    verdict_message: list[str],
    effort_unit: str,
) -> dict[str, Any]:  # JSON values of several types
    """One axis's shadow figures from its residuals (per sample; `twin_ok`: the twin's state
    was finite) and its health verdicts, in order: the in-process shadow and the node set's bag
    give them alike. `health` is the worst level; effect and message are the last named ones."""
    fe = fe_dev_m[twin_ok]
    effort = effort_dev[twin_ok]
    effort = effort[np.isfinite(effort)]  # a machine that reports no effort (LinuxCNC) has none
    warned = np.flatnonzero(verdict_level != OK)
    named = [int(k) for k in warned if verdict_effect[k]]
    return {
        "fe_dev_rms_m": float(np.sqrt(np.mean(fe**2))) if len(fe) else float("nan"),
        "effort_dev_rms": float(np.sqrt(np.mean(effort**2))) if len(effort) else None,
        "effort_unit": effort_unit,
        "health": LEVEL_NAMES[int(verdict_level.max()) if len(verdict_level) else OK],
        "first_warning_s": float(verdict_t_s[warned[0]]) if len(warned) else None,
        "effect": verdict_effect[named[-1]] if named else "",
        "message": verdict_message[named[-1]] if named else "",
    }


def format_axis_figures(axis: str, f: dict[str, Any]) -> str:
    """One line of an axis's shadow figures (`axis_figures`) for the summary."""
    said = f" from {f['first_warning_s']:.3f} s: {f['message']}" if f["first_warning_s"] else ""
    effort = f["effort_dev_rms"]
    effort = shown(effort, f["effort_unit"], digits=4, missing="no effort measured")
    return (
        f"shadow {axis}: FE deviation RMS {shown(f['fe_dev_rms_m'], 'um', scale=1e6)}, "
        f"effort deviation RMS {effort}, health {f['health']}{said}"
    )


def axis_shadow_config(machine: MachineConfig, axis: str) -> ShadowConfig:
    config = machine.axes[axis]
    if config.shadow is None:
        raise ConfigError(
            f"{config.source}: axis {axis}: no shadow: section (the shadow twin's limits and "
            "its stand-in)"
        )
    return load_shadow_config({"shadow": config.shadow}, source=config.source)


def shadow_machine(
    machine: MachineConfig, program: str | Path, *, settle_s: float = 0.0
) -> dict[str, AxisShadow]:
    """Shadow every simulated axis of the machine on `program` (module docstring). A machine
    streams the program's samples and the node set's stand-ins end with them: `settle_s` adds
    samples at rest after the end only here."""
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
        effort_sample=EFFORT_SAMPLE,
    )
    nominal = {name: standin.parameter(name) for name in standin.friction_parameters()}
    # the sample each step acts from, as the stand-in node plays it (first k * period >= at_s)
    steps = sorted(
        (math.ceil((s.at_s - STEP_TOLERANCE_S) / cfg.sample_period_s), s.scale)
        for s in cfg.standin.friction_steps
    )
    chunk = max(1, round(cfg.evaluate_period_s / cfg.sample_period_s))
    blocks: list[ResidualBlock] = []
    verdicts: list[Verdict] = []
    for k0 in range(0, len(t), chunk):
        k1 = min(len(t), k0 + chunk)
        measured = []
        k = k0
        while k < k1:
            while steps and steps[0][0] <= k:
                _, scale = steps.pop(0)
                for name, value in nominal.items():
                    standin.set_parameter(name, value * scale)
            stop = min(k1, steps[0][0]) if steps else k1
            measured.append(standin.step(x[k:stop], v[k:stop], a[k:stop]))
            k = stop
        x_meas = np.concatenate([m[0] for m in measured])
        effort = np.concatenate([m[1] for m in measured])
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
