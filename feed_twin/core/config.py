"""Typed YAML loading: frozen parameter dataclasses from mappings, with errors that say where.

Every parameter class in feed_twin is a frozen, keyword-only dataclass that validates itself in
`__post_init__` with the `require_*` helpers of feed_twin.core.validate. `from_mapping` builds
one from a YAML mapping, rejects unknown keys and missing fields, converts nested dataclasses,
tuples and literals, and re-raises any `ValueError` prefixed with the file and the dotted
field path, so a user reads `config/axis.yaml: plant.table.m = -3.0: must be > 0`.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeVar, cast

import yaml

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")
# Largest config file read [bytes]: configs are a few kB, and a runaway file (a 100 MB list took
# minutes and 2.4 GB to parse) is refused before YAML sees it.
MAX_CONFIG_BYTES = 4_000_000


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or outside its range."""


def load_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML file whose top level is a mapping; errors name the file (and line)."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            raw = handle.read(MAX_CONFIG_BYTES + 1)
        if len(raw) > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"{path}: larger than {MAX_CONFIG_BYTES // 1_000_000} MB; a configuration is a "
                "few kB (is this the right file?)"
            )
        text = raw.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a config file") from None
    except PermissionError:
        raise ConfigError(f"{path}: not readable (permission denied)") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(f"{where}: invalid YAML: {problem}") from None
    if data is None:
        raise ConfigError(f"{path}: the file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping, not {type(data).__name__}")
    return cast(dict[str, Any], data)


def from_mapping(cls: type[T], data: Any, *, source: str, path: str = "") -> T:
    """Build the frozen dataclass `cls` from `data`, validating keys, types and ranges."""
    where = f"{source}: {path}" if path else source
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(data).__name__} {data!r}")
    data = cast(dict[str, Any], data)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(map(str, unknown))}; allowed: {', '.join(fields)}"
        )
    missing = [
        name
        for name, f in fields.items()
        if name not in data
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise ConfigError(f"{where}: missing required field(s) {', '.join(missing)}")
    hints = typing.get_type_hints(cls)
    kwargs = {
        name: _convert(hints[name], value, source=source, path=_join(path, name))
        for name, value in data.items()
    }
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except ValueError as exc:
        prefix = f"{source}: {path}." if path else f"{source}: "
        raise ConfigError(f"{prefix}{exc}") from None


def _join(path: str, name: str | int) -> str:
    if isinstance(name, int):
        return f"{path}[{name}]"
    return f"{path}.{name}" if path else name


def _convert(hint: Any, value: Any, *, source: str, path: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return _convert_union(hint, value, source=source, path=path)
    if origin is Literal:
        args = typing.get_args(hint)
        if value not in args:
            choices = ", ".join(repr(a) for a in args)
            raise ConfigError(f"{source}: {path} = {value!r}: must be one of {choices}")
        return value
    if origin is tuple:
        return _convert_tuple(hint, value, source=source, path=path)
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return from_mapping(hint, value, source=source, path=path)
    if hint is Any:
        return value
    if hint not in _SCALARS:
        raise TypeError(f"from_mapping cannot convert to {hint!r} (field {path})")
    accepts, expected = _SCALARS[hint]
    if not accepts(value):
        raise ConfigError(f"{source}: {path} = {value!r}: expected {expected}")
    return float(value) if hint is float else value


# scalar type -> (does a YAML value convert to it, what the message says is expected); a bool
# is not a number here, although Python's bool is an int
_SCALARS: dict[Any, tuple[Callable[[Any], bool], str]] = {
    float: (lambda v: not isinstance(v, bool) and isinstance(v, int | float), "a number"),
    int: (lambda v: not isinstance(v, bool) and isinstance(v, int), "a whole number"),
    bool: (lambda v: isinstance(v, bool), "true or false"),
    str: (lambda v: isinstance(v, str), "a string"),
}


def _convert_union(hint: Any, value: Any, *, source: str, path: str) -> Any:
    args = typing.get_args(hint)
    if value is None and type(None) in args:
        return None
    errors: list[str] = []
    for option in (a for a in args if a is not type(None)):
        try:
            return _convert(option, value, source=source, path=path)
        except ConfigError as exc:
            errors.append(str(exc))
    raise ConfigError(
        errors[0] if len(errors) == 1 else f"{source}: {path} = {value!r}: " + "; ".join(errors)
    )


def _convert_tuple(hint: Any, value: Any, *, source: str, path: str) -> tuple[Any, ...]:
    args: tuple[Any, ...] = typing.get_args(hint)
    if not isinstance(value, list | tuple):
        raise ConfigError(f"{source}: {path} = {value!r}: expected a list")
    value = cast(list[Any] | tuple[Any, ...], value)
    if len(args) == 2 and args[1] is Ellipsis:
        args = (args[0],) * len(value)
    elif len(args) != len(value):
        raise ConfigError(f"{source}: {path} = {value!r}: expected {len(args)} entries")
    return tuple(
        _convert(a, v, source=source, path=_join(path, i))
        for i, (a, v) in enumerate(zip(args, value, strict=True))
    )
