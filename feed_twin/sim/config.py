"""One axis YAML, all sections: `plant:` (feed_twin.plant.config), `engine:` (here),
`controller:` (feed_twin.control.config.load_controller_config), and `nc:`, `shadow:` and `ros:`
(kept as mappings for the G-code stage, the shadow twin and the node set, which load them).

    axis = load_axis_config("config/axis_default.yaml")      # or a parsed mapping
    engine = build_engine(axis)                               # closed loop, as configured
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.assembly import PlantModel
from feed_twin.plant.config import load_plant
from feed_twin.sim.engine import Engine

# `analysis`: what the discrepancy workflow writes beside a fitted model (analysis.twin.ModelDoc)
SECTIONS = ("plant", "engine", "controller", "nc", "shadow", "ros", "analysis")


@dataclass(frozen=True, kw_only=True)
class EngineConfig:
    base_period_s: float  # base tick [s]: the fastest controller period
    substeps: int  # RK4 steps per base tick
    output_period_s: float  # recording period [s], an integer multiple of the base period
    seed: int  # seed of the sensor noise
    # compile the parameter values into the kernel: about 10 % faster per tick, one kernel
    # (about 12 s, then cached) per parameter set, which is then fixed (Engine)
    inline_parameters: bool = False

    def __post_init__(self) -> None:
        require_positive("base_period_s", self.base_period_s)
        if self.substeps < 1:
            raise ValueError(f"substeps = {self.substeps!r}: must be >= 1")
        require_positive("output_period_s", self.output_period_s)
        ratio = self.output_period_s / self.base_period_s
        if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
            raise ValueError(
                f"output_period_s = {self.output_period_s!r}: must be an integer multiple of "
                f"base_period_s = {self.base_period_s!r}"
            )
        require_nonnegative("seed", self.seed)


@dataclass(frozen=True, kw_only=True)
class AxisConfig:
    source: str
    plant: PlantModel
    engine: EngineConfig
    controller: Any  # feed_twin.control.config.ControllerConfig, or None
    nc: Mapping[str, Any] | None
    shadow: Mapping[str, Any] | None
    ros: Mapping[str, Any] | None
    raw: Mapping[str, Any]


def load_axis_config(
    path: str | Path | Mapping[str, Any], *, source: str | None = None
) -> AxisConfig:
    """Read every section of an axis YAML file (or of an already parsed mapping)."""
    if isinstance(path, Mapping):
        data = dict(path)
        source = source or "<mapping>"
    else:
        data = load_yaml(path)
        source = source or str(path)
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise ConfigError(
            f"{source}: unknown section(s) {', '.join(map(str, unknown))}; "
            f"allowed: {', '.join(SECTIONS)}"
        )
    for section in ("plant", "engine"):
        if section not in data:
            raise ConfigError(f"{source}: missing required section {section}")
    plant = load_plant(data["plant"], source=source)
    engine = from_mapping(EngineConfig, data["engine"], source=source, path="engine")
    controller = None
    if data.get("controller") is not None:
        from feed_twin.control.config import load_controller_config

        controller = load_controller_config(data["controller"], source=source)
        if abs(controller.base_period_s - engine.base_period_s) > 1e-12 * engine.base_period_s:
            raise ConfigError(
                f"{source}: engine.base_period_s = {engine.base_period_s!r}: must equal "
                f"controller.base_period_s = {controller.base_period_s!r}"
            )
    return AxisConfig(
        source=source,
        plant=plant,
        engine=engine,
        controller=controller,
        nc=data.get("nc"),
        shadow=data.get("shadow"),
        ros=data.get("ros"),
        raw=data,
    )


def build_engine(
    axis: AxisConfig,
    *,
    closed_loop: bool = True,
    mode: str | None = None,
    params: np.ndarray | None = None,
    record: Sequence[str] | None = None,
    output_period_s: float | None = None,
) -> Engine:
    """An Engine for the axis: with its controller (optionally at another CiA 402 `mode`) or open
    loop (`closed_loop=False`: drive rows are prescribed per tick)."""
    cascade = None
    if closed_loop:
        if axis.controller is None:
            raise ConfigError(f"{axis.source}: closed loop needs a controller section")
        from feed_twin.control.layout import build_cascade, with_mode

        cascade = build_cascade(axis.controller)
        if mode is not None:
            cascade = with_mode(cascade, mode)
    return Engine(
        axis.plant,
        base_period_s=axis.engine.base_period_s,
        substeps=axis.engine.substeps,
        output_period_s=output_period_s or axis.engine.output_period_s,
        seed=axis.engine.seed,
        controller=cascade,
        params=params,
        record=record,
        inline_parameters=axis.engine.inline_parameters,
    )
