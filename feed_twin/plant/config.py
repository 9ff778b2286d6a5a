"""The `plant:` section of an axis YAML: a list of components and the connections of their ports.

    plant:
      components:
        - {name: table, type: Mass, params: {m: 95.1}}
        - {name: friction, type: GuideFriction, params: {F_c_pos: 20.4, ...}}
      connect:
        - [table.flange, friction.flange]

Each entry's `params` go through `from_mapping` into the component's dataclass, so unknown keys,
missing fields and non-physical values fail as `file: plant.<name>.<field> = value: reason`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from feed_twin.core.config import ConfigError, from_mapping
from feed_twin.plant.assembly import AssemblyError, PlantModel
from feed_twin.plant.component import Component, check_name
from feed_twin.plant.plausible import check_plausible
from feed_twin.plant.registry import COMPONENT_TYPES

_ENTRY_KEYS = ("name", "type", "params")


def load_plant(data: Any, *, source: str) -> PlantModel:
    """Assemble the PlantModel described by the `plant:` mapping `data`."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: plant: expected a mapping, got {type(data).__name__}")
    unknown = sorted(set(data) - {"components", "connect", "unusual"})
    if unknown:
        raise ConfigError(
            f"{source}: plant: unknown key(s) {', '.join(map(str, unknown))}; "
            "allowed: components, connect, unusual"
        )
    unusual = data.get("unusual") or []
    if not isinstance(unusual, list) or not all(isinstance(n, str) for n in unusual):
        raise ConfigError(
            f"{source}: plant.unusual = {unusual!r}: expected a list of component.parameter"
        )
    for key in ("components", "connect"):
        if key not in data:
            raise ConfigError(f"{source}: plant: missing required field(s) {key}")
        if not isinstance(data[key], list):
            raise ConfigError(f"{source}: plant.{key}: expected a list, got {data[key]!r}")
    components = [_component(entry, i, source) for i, entry in enumerate(data["components"])]
    connections = []
    for i, pair in enumerate(data["connect"]):
        if (
            not isinstance(pair, list)
            or len(pair) != 2
            or not all(isinstance(p, str) for p in pair)
        ):
            raise ConfigError(
                f"{source}: plant.connect[{i}] = {pair!r}: expected [component.port, "
                "component.port]"
            )
        connections.append((pair[0], pair[1]))
    check_plausible(dict(components), unusual, source)
    try:
        return PlantModel(components, connections, source=source)
    except AssemblyError as exc:
        raise ConfigError(str(exc)) from None


def _component(entry: Any, i: int, source: str) -> tuple[str, Component]:
    where = f"{source}: plant.components[{i}]"
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where} = {entry!r}: expected a mapping with name, type, params")
    unknown = sorted(set(entry) - set(_ENTRY_KEYS))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(map(str, unknown))}; allowed: name, type, params"
        )
    missing = [k for k in _ENTRY_KEYS if k not in entry]
    if missing:
        raise ConfigError(f"{where}: missing required field(s) {', '.join(missing)}")
    name = entry["name"]
    if not isinstance(name, str):
        raise ConfigError(f"{where}.name = {name!r}: expected a string")
    try:
        check_name(name)
    except ValueError as exc:
        raise ConfigError(f"{where}.{exc}") from None
    kind = entry["type"]
    if kind not in COMPONENT_TYPES:
        raise ConfigError(
            f"{source}: plant.{name}.type = {kind!r}: unknown component type; "
            f"known: {', '.join(sorted(COMPONENT_TYPES))}"
        )
    params = entry["params"] if entry["params"] is not None else {}
    return name, from_mapping(COMPONENT_TYPES[kind], params, source=source, path=f"plant.{name}")
