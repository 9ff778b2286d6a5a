"""CDR encoding of flat ROS 2 messages with `struct`, for the node set's per-exchange topics.

A lockstep exchange publishes and receives several messages per millisecond; building rclpy
message objects, setting their checked fields and converting them costs 20-40 us each, which is
most of the node set's CPU. The hot messages (AxisCommand, DriveCommand, AxisFeedback,
AxisState) are flat: a std_msgs/Header, strings and numbers. `FlatCodec` reads the installed
`.msg` definition and packs/unpacks exactly the bytes rmw would put on the wire (XCDR1 little
endian: a 4-byte encapsulation header, then every primitive aligned to its size counted from
the end of that header, strings as uint32 length including the NUL, then the bytes and NUL).
Publishers send the bytes with `publish(bytes)`; subscribers take them with `raw=True`.
A test checks the bytes against rclpy's serialiser field by field.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import cache

from feed_twin.io.bag_schema import package_share, split_type_name

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
_PRIMITIVES = {
    "bool": "?",
    "byte": "B",
    "char": "B",
    "int8": "b",
    "uint8": "B",
    "int16": "h",
    "uint16": "H",
    "int32": "i",
    "uint32": "I",
    "int64": "q",
    "uint64": "Q",
    "float32": "f",
    "float64": "d",
}
# Nested types that are themselves flat, expanded in place.
_EXPANSIONS = {
    "std_msgs/Header": (
        ("stamp.sec", "int32"),
        ("stamp.nanosec", "uint32"),
        ("frame_id", "string"),
    ),
    "builtin_interfaces/Time": (("sec", "int32"), ("nanosec", "uint32")),
    "builtin_interfaces/Duration": (("sec", "int32"), ("nanosec", "uint32")),
}


class NotFlatError(TypeError):
    """The message has arrays or nested types that FlatCodec does not handle."""


def flat_fields(type_name: str) -> tuple[tuple[str, str], ...]:
    """(dotted field name, primitive type or 'string') of a flat message, in wire order."""
    package, name = split_type_name(type_name)
    text = (package_share(package) / "msg" / f"{name}.msg").read_text(encoding="utf-8")
    fields: list[tuple[str, str]] = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line:
            continue  # blank, comment or constant
        type_token, field_name = line.split()[:2]
        key = type_token
        if key in _PRIMITIVES or key == "string":
            fields.append((field_name, key))
        elif key in _EXPANSIONS:
            fields.extend((f"{field_name}.{sub}", t) for sub, t in _EXPANSIONS[key])
        else:
            raise NotFlatError(
                f"{type_name}: field {field_name!r} of type {type_token!r} is not flat"
            )
    return tuple(fields)


class FlatCodec:
    """Pack and unpack one flat message type; values are tuples in `fields` order."""

    def __init__(self, type_name: str) -> None:
        self.type_name = type_name
        self.fields = flat_fields(type_name)
        self.names = tuple(name for name, _ in self.fields)
        self._strings = tuple(i for i, (_, t) in enumerate(self.fields) if t == "string")
        self._tail_start = (self._strings[-1] + 1) if self._strings else 0

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.type_name} has no field {name!r}") from None

    @cache  # noqa: B019 - one codec per message type lives for the whole process
    def _format(self, string_lengths: tuple[int, ...]) -> struct.Struct:
        parts = ["<"]
        offset = 0
        lengths = iter(string_lengths)
        for _, kind in self.fields:
            if kind == "string":
                n = next(lengths) + 1
                pad = -offset % 4
                parts.append(f"{pad}xI{n}s")
                offset += pad + 4 + n
                continue
            code = _PRIMITIVES[kind]
            size = struct.calcsize(code)
            pad = -offset % size
            parts.append(f"{pad}x{code}")
            offset += pad + size
        return struct.Struct("".join(parts))

    def encode(self, values: Sequence) -> bytes:
        """CDR bytes of the message; strings are given as str."""
        args: list = []
        lengths: list[int] = []
        for (_, kind), value in zip(self.fields, values, strict=True):
            if kind == "string":
                data = value.encode("utf-8")
                lengths.append(len(data))
                args.append(len(data) + 1)
                args.append(data)
            else:
                args.append(value)
        return ENCAPSULATION + self._format(tuple(lengths)).pack(*args)

    def decode(self, data: bytes) -> tuple:
        """Values in `fields` order (strings as str) from CDR bytes."""
        if data[:2] != ENCAPSULATION[:2]:
            raise ValueError(f"{self.type_name}: not little-endian CDR (header {data[:4]!r})")
        lengths: list[int] = []
        offset = 0
        for _, kind in self.fields[: self._tail_start]:
            if kind == "string":
                offset += -offset % 4
                (n,) = struct.unpack_from("<I", data, 4 + offset)
                lengths.append(n - 1)
                offset += 4 + n
            else:
                size = struct.calcsize(_PRIMITIVES[kind])
                offset += -offset % size + size
        raw = self._format(tuple(lengths)).unpack_from(data, 4)
        out: list = []
        it = iter(raw)
        for _, kind in self.fields:
            if kind == "string":
                next(it)  # the length
                out.append(next(it)[:-1].decode("utf-8"))
            else:
                out.append(next(it))
        return tuple(out)

    def encode_map(self, values: dict) -> bytes:
        """CDR bytes from a name -> value mapping; absent fields are 0 or ''."""
        unknown = set(values) - set(self.names)
        if unknown:
            raise KeyError(f"{self.type_name} has no field(s) {', '.join(sorted(unknown))}")
        return self.encode(
            [values.get(name, "" if kind == "string" else 0) for name, kind in self.fields]
        )

    def decode_map(self, data: bytes) -> dict:
        return dict(zip(self.names, self.decode(data), strict=True))
