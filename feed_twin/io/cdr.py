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

`FlatCodec.fixed(...)` gives a `FixedLayout` for the per-exchange hot path: the strings of a
node's messages never change during a run (frame_id: the run token or '', the axis label), so
the whole message is one precompiled `struct` and a message packs or unpacks in about 1 us,
numbers only.
"""

from __future__ import annotations

import operator
import struct
from collections.abc import Mapping, Sequence
from functools import cache

from feed_twin.io.bag.schema import package_share, split_type_name

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

    def fixed(self, strings: Mapping[str, str]) -> FixedLayout:
        """The layout of this message with its string fields set to `strings` (absent: '')."""
        return FixedLayout(self, strings)


class FixedLayout:
    """One flat message type with fixed strings: its numbers <-> CDR bytes in one struct call.

    `numbers` names the non-string fields in wire order; `encode(values)` takes them in that
    order. `decode(data)` returns them as a tuple; a message whose strings differ from the
    layout's (another axis label, a frame_id) is decoded by the general path, so any valid
    message is read correctly, only slower.
    """

    def __init__(self, codec: FlatCodec, strings: Mapping[str, str]) -> None:
        string_names = {name for name, kind in codec.fields if kind == "string"}
        unknown = set(strings) - string_names
        if unknown:
            raise KeyError(f"{codec.type_name} has no string field(s) {', '.join(sorted(unknown))}")
        self.codec = codec
        self.strings = {name: strings.get(name, "") for name in string_names}
        self.numbers = tuple(name for name, kind in codec.fields if kind != "string")
        template: list = []
        slots: list[int] = []  # position of each number in the struct's argument list
        for name, kind in codec.fields:
            if kind == "string":
                data = self.strings[name].encode("utf-8")
                template += [len(data) + 1, data + b"\0"]
            else:
                slots.append(len(template))
                template.append(0)
        lengths = tuple(
            len(self.strings[n].encode("utf-8")) for n, k in codec.fields if k == "string"
        )
        self._struct = codec._format(lengths)
        self._template = template
        self._slots = tuple(slots)
        # Runs of consecutive number slots: encode copies each run with one slice assignment.
        runs: list[tuple[int, int, int]] = []
        for i, slot in enumerate(slots):
            if runs and runs[-1][0] + runs[-1][2] == slot:
                start, first, count = runs[-1]
                runs[-1] = (start, first, count + 1)
            else:
                runs.append((slot, i, 1))
        self._runs = tuple((start, start + n, first, first + n) for start, first, n in runs)
        self._pick = operator.itemgetter(*slots) if len(slots) > 1 else None
        self.size = len(ENCAPSULATION) + self._struct.size
        reference = self._struct.pack(*template)
        # The bytes a message must have to take the fast path: the encapsulation header and the
        # strings with their length prefixes, as (start, stop, bytes) in the whole message.
        checks = [(0, 2, ENCAPSULATION[:2])]
        for start, stop in self._string_spans(codec, lengths):
            checks.append((4 + start, 4 + stop, reference[start:stop]))
        self._checks = tuple(checks)

    def _string_spans(self, codec: FlatCodec, lengths: tuple[int, ...]) -> list[tuple[int, int]]:
        spans = []
        offset = 0
        it = iter(lengths)
        for _, kind in codec.fields:
            if kind == "string":
                offset += -offset % 4
                n = next(it) + 1
                spans.append((offset, offset + 4 + n))
                offset += 4 + n
            else:
                size = struct.calcsize(_PRIMITIVES[kind])
                offset += -offset % size + size
        return spans

    def index(self, name: str) -> int:
        """Position of the number field `name` in `numbers`."""
        try:
            return self.numbers.index(name)
        except ValueError:
            raise KeyError(f"{self.codec.type_name} has no number field {name!r}") from None

    def encode(self, values: Sequence) -> bytes:
        """CDR bytes of the message with these numbers (in `numbers` order)."""
        if len(values) != len(self._slots):
            raise ValueError(
                f"{self.codec.type_name}: {len(values)} values given, "
                f"{len(self._slots)} number fields expected"
            )
        args = list(self._template)
        for start, stop, first, last in self._runs:
            args[start:stop] = values[first:last]
        return ENCAPSULATION + self._struct.pack(*args)

    def matches(self, data: bytes) -> bool:
        """The message carries exactly this layout's strings (it takes the fast path)."""
        return len(data) == self.size and all(
            data[start:stop] == expected for start, stop, expected in self._checks
        )

    def decode(self, data: bytes) -> tuple:
        """The numbers of a message (in `numbers` order)."""
        if len(data) == self.size:
            for start, stop, expected in self._checks:
                if data[start:stop] != expected:
                    break
            else:
                raw = self._struct.unpack_from(data, 4)
                return self._pick(raw) if self._pick is not None else (raw[self._slots[0]],)
        values = self.codec.decode(data)
        return tuple(
            v for (_, kind), v in zip(self.codec.fields, values, strict=True) if kind != "string"
        )


class JointStateLayout:
    """sensor_msgs/JointState of one named joint, empty frame_id: (sec, nanosec, position,
    velocity, effort) -> the CDR bytes, padding zeroed as on the wire (rclpy's
    `serialize_message` leaves whatever was in its buffer in the padding)."""

    def __init__(self, joint_name: str) -> None:
        name = joint_name.encode("utf-8") + b"\0"
        fmt, offset = ["<"], 0

        def add(code: str, size: int, align: int) -> None:
            nonlocal offset
            pad = -offset % align
            fmt.append(f"{pad}x{code}" if pad else code)
            offset += pad + size

        add("i", 4, 4)  # header.stamp.sec
        add("I", 4, 4)  # header.stamp.nanosec
        add("I", 4, 4)  # header.frame_id: length 1 (the NUL)
        add("1s", 1, 1)
        add("I", 4, 4)  # name: one string
        add("I", 4, 4)
        add(f"{len(name)}s", len(name), 1)
        for _ in ("position", "velocity", "effort"):
            add("I", 4, 4)  # one value
            add("d", 8, 8)
        self._struct = struct.Struct("".join(fmt))
        self._name = name

    def encode(self, sec: int, nanosec: int, position: float, velocity: float, effort: float):
        return ENCAPSULATION + self._struct.pack(
            sec, nanosec, 1, b"\0", 1, len(self._name), self._name,
            1, position, 1, velocity, 1, effort,
        )  # fmt: skip
