"""One machine YAML: the NC section once and a plant + drive per simulated linear axis.

    machine: cnc
    nc: {...}                      # feed_twin.gcode.config.NcConfig (linear and rotary axes)
    axes:
      X: {include: axis_default.yaml}
      Z:
        include: axis_default.yaml
        vertical: {flange: table.flange, m_kg: 200.0,
                   counterbalance: {type: constant_force, f_N: 1500.0}}

An axis entry either includes an axis file by reference (its `plant:`, `engine:`,
`controller:` and `shadow:` sections; its `nc:` and `ros:` are the single-axis run's and are not
read) or holds those sections inline; an entry's own `shadow:` replaces the included one (the
stand-in of that axis, its hidden effects, the shadow twin's limits). `vertical:` adds the
axis's weight (plant.gravity) and a counterbalance to the plant, so one drive file serves a
horizontal and a vertical axis. Axes of the NC without an entry (rotary axes, for one) are
planned and recorded as commands only.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.gcode.config import NcConfig, nc_config_from_mapping
from feed_twin.sim.config import AxisConfig, load_axis_config

MACHINE_SECTIONS = ("machine", "nc", "axes", "ros")
AXIS_ENTRY_KEYS = ("include", "plant", "engine", "controller", "shadow", "vertical")
STANDARD_GRAVITY = 9.80665  # [m/s^2]


@dataclass(frozen=True, kw_only=True)
class Counterbalance:
    """What holds a vertical slide up besides its drive.

    constant_force: f = f_N (a hydraulic cylinder at constant pressure, or a counterweight's
    pull whose mass is counted in m_kg). gas_spring (plant.gas_spring): f = f_N - k (s - s_0),
    stiffer as the slide goes down and compresses the gas.
    """

    type: Literal["constant_force", "gas_spring"]
    f_N: float  # [N] upward force (gas spring: at s = s_0_m)
    s_0_m: float = 0.0  # [m] slide position where the gas spring pushes f_N
    k_N_m: float = 0.0  # [N/m] the gas spring's force rise per metre downwards

    def __post_init__(self) -> None:
        require_positive("f_N", self.f_N)
        require_finite("s_0_m", self.s_0_m)
        require_nonnegative("k_N_m", self.k_N_m)
        if self.type == "constant_force" and (self.s_0_m != 0.0 or self.k_N_m != 0.0):
            raise ValueError(
                f"s_0_m, k_N_m = {self.s_0_m!r}, {self.k_N_m!r}: only a gas_spring has them"
            )


@dataclass(frozen=True, kw_only=True)
class Vertical:
    """The axis moves along gravity, positive up: its weight and counterbalance join the plant."""

    flange: str  # port the weight acts on, e.g. table.flange
    m_kg: float  # [kg] the moving mass gravity pulls on (slide, spindle head, workpiece)
    g_m_s2: float = STANDARD_GRAVITY  # [m/s^2]
    counterbalance: Counterbalance | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.flange, str) or self.flange.count(".") != 1:
            raise ValueError(f"flange = {self.flange!r}: must read component.port")
        require_positive("m_kg", self.m_kg)
        require_positive("g_m_s2", self.g_m_s2)


@dataclass(frozen=True, kw_only=True)
class MachineConfig:
    """The NC of the machine and the axis model of each simulated axis, in the NC's order."""

    source: str
    name: str  # ROS namespace of the machine (/name/x, /name/y, ...)
    nc: NcConfig
    axes: dict[str, AxisConfig]  # NC axis name -> its plant, engine and controller
    verticals: dict[str, Vertical]  # the vertical axes among them
    axis_file: bool = False  # an axis YAML run as a one-axis machine (load_run_config)

    @property
    def simulated(self) -> tuple[str, ...]:
        return tuple(self.axes)

    def select(self, names: Sequence[str]) -> MachineConfig:
        """The same machine simulating only `names` (`--axes X,Z`); the others stay commands."""
        chosen = []
        for name in names:
            key = name.strip().upper()
            if key not in self.axes:
                raise ConfigError(
                    f"{self.source}: --axes {','.join(names)}: axis {key} has no plant "
                    f"(simulated axes: {', '.join(self.axes)})"
                )
            if key in chosen:
                raise ConfigError(f"{self.source}: --axes {','.join(names)}: {key} twice")
            chosen.append(key)
        order = [a for a in self.axes if a in chosen]
        return MachineConfig(
            source=self.source,
            name=self.name,
            nc=self.nc,
            axes={a: self.axes[a] for a in order},
            verticals={a: v for a, v in self.verticals.items() if a in chosen},
            axis_file=self.axis_file,
        )


def is_machine_config(data: Mapping[str, Any]) -> bool:
    """A machine file has an `axes:` mapping at the top; an axis file has `plant:`."""
    return isinstance(data.get("axes"), Mapping) and "plant" not in data


def is_machine_file(path: str | Path) -> bool:
    """A machine YAML rather than one axis's; an unreadable file is not."""
    try:
        return is_machine_config(load_yaml(Path(path)))
    except ConfigError:
        return False


def load_run_config(path: str | Path) -> MachineConfig:
    """Any config a run takes as a machine: a machine YAML as `load_machine_config`, an axis
    YAML as a one-axis machine (its `nc:` section's NC, its `ros.machine` name, its plant as
    the NC's twin_axis). Errors name the file and field."""
    if is_machine_config(load_yaml(Path(path))):
        return load_machine_config(path)
    return one_axis_machine(load_axis_config(path))


def one_axis_machine(axis: AxisConfig) -> MachineConfig:
    """The axis as a machine of one simulated axis, the NC's twin_axis (its other NC axes, if
    any, are commands only)."""
    if axis.nc is None:
        raise ConfigError(f"{axis.source}: running a program needs an nc: section")
    nc = nc_config_from_mapping(axis.nc, source=axis.source)
    ros = axis.ros if isinstance(axis.ros, Mapping) else {}
    name = ros.get("machine", "cnc")
    if not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(
            f"{axis.source}: ros.machine = {name!r}: must be a ROS name (letters, _, digits)"
        )
    return MachineConfig(source=axis.source, name=name, nc=nc, axes={nc.twin_axis: axis},
                         verticals={}, axis_file=True)  # fmt: skip


def load_machine_config(path: str | Path) -> MachineConfig:
    """Read a machine YAML and every axis file it includes; errors name the file and field."""
    path = Path(path)
    data = load_yaml(path)
    source = str(path)
    unknown = sorted(set(data) - set(MACHINE_SECTIONS))
    if unknown:
        raise ConfigError(
            f"{source}: unknown section(s) {', '.join(map(str, unknown))}; "
            f"allowed: {', '.join(MACHINE_SECTIONS)}"
        )
    for section in ("nc", "axes"):
        if section not in data:
            raise ConfigError(f"{source}: missing required section {section}")
    entries = data["axes"]
    if not isinstance(entries, Mapping) or not entries:
        raise ConfigError(f"{source}: axes: expected a mapping of axis name -> axis entry")
    nc_data = data["nc"]
    if isinstance(nc_data, Mapping) and "twin_axis" not in nc_data:
        # the machine simulates several axes; twin_axis keeps its single-axis meaning for
        # whoever reads this NC alone: the first simulated one
        linear = [a.get("name") for a in nc_data.get("axes", []) if isinstance(a, Mapping)]
        simulated = [key for key in entries if key in linear]
        nc_data = {**nc_data, "twin_axis": simulated[0] if simulated else "X"}
    nc = nc_config_from_mapping(nc_data, source=source)
    name = data.get("machine", "cnc")
    if not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(f"{source}: machine = {name!r}: must be a ROS name (letters, _, digits)")
    axes: dict[str, AxisConfig] = {}
    verticals: dict[str, Vertical] = {}
    for key in nc.axis_names:
        if key not in entries:
            continue
        axis, vertical = _axis_entry(entries[key], key, nc, path)
        axes[key] = axis
        if vertical is not None:
            verticals[key] = vertical
    for key in entries:
        if key not in nc.axis_names:
            raise ConfigError(
                f"{source}: axes.{key}: the NC has no axis {key} "
                f"(nc.axes: {', '.join(nc.axis_names)})"
            )
    return MachineConfig(source=source, name=name, nc=nc, axes=axes, verticals=verticals)


def _axis_entry(
    entry: Any, key: str, nc: NcConfig, path: Path
) -> tuple[AxisConfig, Vertical | None]:
    sections, axis_source, vertical = axis_sections(entry, key, nc, path)
    return load_axis_config(sections, source=axis_source), vertical


def axis_sections(
    entry: Any, key: str, nc: NcConfig, path: Path
) -> tuple[dict[str, Any], str, Vertical | None]:
    """The plant (weight and counterbalance added), engine, controller and shadow mappings of
    axis entry `key`, the source its errors name, and its vertical description."""
    source = str(path)
    where = f"{source}: axes.{key}"
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where}: expected a mapping, got {entry!r}")
    unknown = sorted(set(entry) - set(AXIS_ENTRY_KEYS))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(map(str, unknown))}; "
            f"allowed: {', '.join(AXIS_ENTRY_KEYS)}"
        )
    if nc.axis_kind(key) != "linear":
        raise ConfigError(
            f"{where}: {key} is a rotary axis; only linear axes have a plant "
            "(a rotary axis is planned and recorded as a command)"
        )
    inline = {k: entry[k] for k in ("plant", "engine", "controller") if k in entry}
    if "include" in entry:
        if inline:
            raise ConfigError(
                f"{where}: include and inline {', '.join(inline)} together; use one of them"
            )
        included = path.parent / str(entry["include"])
        try:
            raw = load_yaml(included)
        except ConfigError as exc:
            raise ConfigError(f"{where}.include: {exc}") from None
        sections = {k: raw[k] for k in ("plant", "engine", "controller", "shadow") if k in raw}
        axis_source = f"{included} (axes.{key} of {source})"
    else:
        sections = inline
        axis_source = f"{source}: axes.{key}"
    if entry.get("shadow") is not None:
        sections = {**sections, "shadow": entry["shadow"]}
    vertical = None
    if entry.get("vertical") is not None:
        vertical = from_mapping(
            Vertical, entry["vertical"], source=source, path=f"axes.{key}.vertical"
        )
        sections = {**sections, "plant": _with_weight(sections.get("plant"), vertical, where)}
    return sections, axis_source, vertical


def _with_weight(plant: Any, vertical: Vertical, where: str) -> dict[str, Any]:
    """The plant mapping with the weight (Gravity) and counterbalance on `vertical.flange`."""
    if not isinstance(plant, Mapping) or not isinstance(plant.get("components"), list):
        raise ConfigError(f"{where}: vertical needs a plant with a components list")
    plant = copy.deepcopy(dict(plant))
    names = {c.get("name") for c in plant["components"] if isinstance(c, Mapping)}
    owner = vertical.flange.split(".")[0]
    if owner not in names:
        raise ConfigError(
            f"{where}.vertical.flange = {vertical.flange!r}: the plant has no component {owner}"
        )
    plant["components"].append(
        {
            "name": "gravity",
            "type": "Gravity",
            "params": {
                "m": vertical.m_kg,
                "g": vertical.g_m_s2,
                "incline_deg": 90.0,
                "m_counterweight": 0.0,
            },
        }
    )
    plant["connect"] = [*plant.get("connect", []), [vertical.flange, "gravity.flange"]]
    cb = vertical.counterbalance
    if cb is not None:
        if cb.type == "constant_force":
            entry = {"name": "counterbalance", "type": "ConstantForce", "params": {"f_0": cb.f_N}}
        else:
            params = {"f_0": cb.f_N, "s_0": cb.s_0_m, "k": cb.k_N_m}
            entry = {"name": "counterbalance", "type": "GasSpring", "params": params}
        plant["components"].append(entry)
        plant["connect"].append([vertical.flange, "counterbalance.flange"])
    return plant
