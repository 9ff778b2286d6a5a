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
from typing import cast

from feed_twin.core.config import ConfigError, from_mapping
from feed_twin.plant.assembly import AssemblyError, PlantModel
from feed_twin.plant.component import Component, check_name
from feed_twin.plant.plausible import check_plausible
from feed_twin.plant.registry import COMPONENT_TYPES

_ENTRY_KEYS = ("name", "type", "params")


def load_plant(data: object, *, source: str) -> PlantModel:
    """Assemble the PlantModel described by the `plant:` mapping `data`."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: plant: expected a mapping, got {type(data).__name__}")
    data = cast(Mapping[str, object], data)  # YAML: keys and values are checked below
    unknown = sorted(set(data) - {"components", "connect", "unusual"})
    if unknown:
        raise ConfigError(
            f"{source}: plant: unknown key(s) {', '.join(map(str, unknown))}; "
            "allowed: components, connect, unusual"
        )
    unusual = _list(data.get("unusual") or [])
    names = [n for n in unusual or () if isinstance(n, str)]
    if unusual is None or len(names) != len(unusual):
        raise ConfigError(
            f"{source}: plant.unusual = {data.get('unusual')!r}: expected a list of "
            "component.parameter"
        )
    lists: dict[str, list[object]] = {}
    for key in ("components", "connect"):
        if key not in data:
            raise ConfigError(f"{source}: plant: missing required field(s) {key}")
        value = _list(data[key])
        if value is None:
            raise ConfigError(f"{source}: plant.{key}: expected a list, got {data[key]!r}")
        lists[key] = value
    components = [_component(entry, i, source) for i, entry in enumerate(lists["components"])]
    connections: list[tuple[str, str]] = []
    for i, entry in enumerate(lists["connect"]):
        pair = _list(entry)
        if (
            pair is None
            or len(pair) != 2
            or not isinstance(pair[0], str)
            or not isinstance(pair[1], str)
        ):
            raise ConfigError(
                f"{source}: plant.connect[{i}] = {entry!r}: expected [component.port, "
                "component.port]"
            )
        connections.append((pair[0], pair[1]))
    check_plausible(dict(components), names, source)
    try:
        return PlantModel(components, connections, source=source)
    except AssemblyError as exc:
        raise ConfigError(str(exc)) from None


def _list(value: object) -> list[object] | None:
    """A YAML sequence with its items still to be checked, None if `value` is not one."""
    return cast(list[object], value) if isinstance(value, list) else None


def _component(entry: object, i: int, source: str) -> tuple[str, Component]:
    where = f"{source}: plant.components[{i}]"
    if not isinstance(entry, Mapping):
        raise ConfigError(f"{where} = {entry!r}: expected a mapping with name, type, params")
    entry = cast(Mapping[str, object], entry)  # YAML: keys and values are checked below
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
    if not isinstance(kind, str) or kind not in COMPONENT_TYPES:
        raise ConfigError(
            f"{source}: plant.{name}.type = {kind!r}: unknown component type; "
            f"known: {', '.join(sorted(COMPONENT_TYPES))}"
        )
    params = entry["params"]
    return name, from_mapping(
        COMPONENT_TYPES[kind], {} if params is None else params, source=source, path=f"plant.{name}"
    )
