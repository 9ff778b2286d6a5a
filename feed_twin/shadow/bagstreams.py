"""A recorded machine's command and measured streams, read from a bag through a column map.

The column map of the discrepancy workflow (feed_twin.io.measured) names, for a bag, each
canonical signal as `<topic>:<field>`. For a replay, the command signals (pos_cmd_m and
optionally vel_cmd_m_s) must come from one topic and the measured ones (pos_meas_m and
optionally the drive effort) from one topic, because each message is one sample of one stream.
Every message keeps its arrival (log) time, so a replay feeds the twin in the order the
machine's messages really arrived, and its stamp: `header.stamp` (the machine's cycle time)
when the type has a header, else the log time.

Decoding: flat types (AxisCommand, AxisFeedback, ...) with the node set's struct codec
(feed_twin.io.cdr), sensor_msgs/JointState with a small CDR reader here (both are about 100x
faster than a generic decoder), anything else with the bag reader's generic decoder.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feed_twin.io import msg_types
from feed_twin.io.bag import BagError, BagReader, info
from feed_twin.io.bag.raw import RawTopic, column, flat_offsets, raw_messages
from feed_twin.io.cdr import FlatCodec, NotFlatError
from feed_twin.io.measured import ColumnMap, ColumnSpec, MeasuredDataError, _to_si

COMMAND_SIGNALS = ("pos_cmd_m", "vel_cmd_m_s")
MEASURED_SIGNALS = ("pos_meas_m", "force_cmd_N", "torque_cmd_Nm", "current_q_A")
_ARRAYS = ("position", "velocity", "effort")


@dataclass(frozen=True, kw_only=True, eq=False)
class Stream:
    """One topic's samples in arrival order, converted to SI."""

    topic: str
    type_name: str
    log_time_ns: np.ndarray  # int64
    stamp_s: np.ndarray  # the machine's stamp of each sample [s]
    signals: dict[str, np.ndarray]  # canonical name -> SI values


def _topic_of(spec: ColumnSpec, name: str, source: str) -> tuple[str, str]:
    topic, sep, field = spec.column.partition(":")
    if not sep or not topic or not field:
        raise MeasuredDataError(
            f"{source}: signals.{name}.column = {spec.column!r}: must read '<topic>:<field>' "
            "for a bag"
        )
    return topic, field


def plan(cmap: ColumnMap) -> dict[str, dict[str, tuple[str, ColumnSpec]]]:
    """{"command": {name: (field, spec)}, "measured": {...}} with one topic each."""
    groups: dict[str, dict[str, tuple[str, str, ColumnSpec]]] = {"command": {}, "measured": {}}
    for name, spec in cmap.signals:
        if name in COMMAND_SIGNALS:
            kind = "command"
        elif name in MEASURED_SIGNALS:
            kind = "measured"
        else:
            continue  # disturbances and other signals are not part of a live stream
        topic, field = _topic_of(spec, name, cmap.source)
        groups[kind][name] = (topic, field, spec)
    for kind, needed in (("command", "pos_cmd_m"), ("measured", "pos_meas_m")):
        if needed not in groups[kind]:
            raise MeasuredDataError(f"{cmap.source}: the map gives no {needed} for the {kind}s")
        topics = {t for t, _, _ in groups[kind].values()}
        if len(topics) > 1:
            raise MeasuredDataError(
                f"{cmap.source}: the {kind} signals come from several topics "
                f"({', '.join(sorted(topics))}); a replay needs each stream on one topic"
            )
    return {
        kind: {name: (f"{topic}:{field}", spec) for name, (topic, field, spec) in g.items()}
        for kind, g in groups.items()
    }


def decode_joint_state(data: bytes) -> dict[str, object]:
    """header.stamp [s], name, position, velocity, effort of a CDR sensor_msgs/JointState."""
    return _joint_state(data)[0]


def _joint_state(data: bytes) -> tuple[dict[str, object], dict[str, tuple[int, str]]]:
    """The decoded fields and, per numeric field, its (byte offset, struct code) in `data`."""
    if data[:2] != b"\x00\x01":
        raise ValueError(f"JointState: not little-endian CDR (header {bytes(data[:4])!r})")

    def align(offset: int, size: int) -> int:
        return offset + (-(offset - 4)) % size  # alignment counts from after the 4-byte header

    sec, nanosec = struct.unpack_from("<iI", data, 4)
    where = {"header.stamp.sec": (4, "<i4"), "header.stamp.nanosec": (8, "<u4")}
    offset = 12
    (n,) = struct.unpack_from("<I", data, offset)
    offset += 4 + n
    offset = align(offset, 4)
    (count,) = struct.unpack_from("<I", data, offset)
    offset += 4
    names = []
    for _ in range(count):
        offset = align(offset, 4)
        (n,) = struct.unpack_from("<I", data, offset)
        names.append(bytes(data[offset + 4 : offset + 3 + n]).decode("utf-8"))
        offset += 4 + n
    out: dict[str, object] = {"header.stamp": sec + nanosec * 1e-9, "name": names}
    for key in _ARRAYS:
        offset = align(offset, 4)
        (count,) = struct.unpack_from("<I", data, offset)
        offset += 4
        if count:
            offset = align(offset, 8)
        out[key] = struct.unpack_from(f"<{count}d", data, offset)
        for i in range(count):
            where[f"{key}[{i}]"] = (offset + 8 * i, "<f8")
        offset += 8 * count
    return out, where


def encode_joint_state(stamp_ns: int, names: list[str], position, velocity, effort) -> bytes:
    """CDR bytes of a sensor_msgs/JointState (frame_id empty), exactly as rmw lays them out."""
    buf = bytearray(b"\x00\x01\x00\x00")

    def pad(size: int) -> None:
        buf.extend(b"\x00" * ((-(len(buf) - 4)) % size))

    buf += struct.pack("<iI", stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
    buf += struct.pack("<I", 1) + b"\x00"
    pad(4)
    buf += struct.pack("<I", len(names))
    for name in names:
        pad(4)
        raw = name.encode("utf-8")
        buf += struct.pack("<I", len(raw) + 1) + raw + b"\x00"
    for values in (position, velocity, effort):
        pad(4)
        buf += struct.pack("<I", len(values))
        if len(values):
            pad(8)
            buf += struct.pack(f"<{len(values)}d", *values)
    return bytes(buf)


def _field(values: dict[str, object], path: str, topic: str) -> float:
    name, index = path, None
    if path.endswith("]") and "[" in path:
        name, _, rest = path.partition("[")
        index = int(rest[:-1])
    if name not in values:
        raise MeasuredDataError(f"topic {topic!r}: message has no field {path!r}")
    value = values[name]
    if index is not None:
        try:
            value = value[index]  # type: ignore[index]
        except IndexError:
            raise MeasuredDataError(
                f"topic {topic!r}: field {path!r} has {len(value)} entries, no [{index}]"  # type: ignore[arg-type]
            ) from None
    return float(value)  # type: ignore[arg-type]


def read_streams(bag: str | Path, cmap: ColumnMap) -> dict[str, Stream]:
    """The command and measured streams of a bag, in arrival order, SI."""
    groups = plan(cmap)
    bag_info = info(bag)
    types = {t.name: t.type_name for t in bag_info.topics}
    wanted: dict[str, tuple[str, dict[str, str], dict[str, ColumnSpec]]] = {}
    for kind, signals in groups.items():
        topic = next(iter(signals.values()))[0].partition(":")[0]
        if topic not in types:
            raise MeasuredDataError(
                f"{bag}: the map names topic {topic!r}, which the bag lacks; it has "
                f"{', '.join(sorted(types))}"
            )
        fields = {name: col.partition(":")[2] for name, (col, _) in signals.items()}
        specs = {name: spec for name, (_, spec) in signals.items()}
        wanted[kind] = (topic, fields, specs)
    fast = {
        topic
        for topic, _, _ in wanted.values()
        if types[topic] == msg_types.JOINT_STATE or _flat(types[topic])
    }
    try:
        collected = raw_messages(bag_info.mcap_path, fast) if fast else {}
    except BagError as exc:
        raise MeasuredDataError(str(exc)) from None
    out: dict[str, Stream] = {}
    for kind, (topic, fields, specs) in wanted.items():
        if topic in fast:
            log_ns, stamps, cols = _decode_fast(topic, types[topic], collected[topic], fields)
        else:
            log_ns, stamps, cols = _decode_generic(bag, topic, fields)
        if len(log_ns) == 0:
            raise MeasuredDataError(f"{bag}: topic {topic!r} has no messages")
        out[kind] = Stream(
            topic=topic,
            type_name=types[topic],
            log_time_ns=log_ns,
            stamp_s=stamps,
            signals={
                name: _to_si(name, specs[name], cols[name], cmap.conversion) for name in fields
            },
        )
    return out


def _flat(type_name: str) -> bool:
    try:
        FlatCodec(type_name)
    except NotFlatError:
        return False
    return True


def _decode_fast(
    topic: str, type_name: str, raw: RawTopic, fields: dict[str, str]
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Arrival order (stable sort by log time); fixed-size messages read as one byte table."""
    order = np.argsort(raw.log_time_ns, kind="stable")
    log_ns = raw.log_time_ns[order]
    codec = None if type_name == msg_types.JOINT_STATE else FlatCodec(type_name)

    def layout(data: bytes) -> dict[str, tuple[int, str]]:
        return _joint_state(data)[1] if codec is None else flat_offsets(codec, data)

    if len(log_ns) == 0:
        return log_ns, np.zeros(0), {name: np.zeros(0) for name in fields}
    if raw.table is not None:
        table = raw.table[order]
        first = layout(table[0].tobytes())
        # one size and the same strings: the layout of the first message is everyone's
        if layout(table[-1].tobytes()) == first:
            missing = [path for path in fields.values() if path not in first]
            if missing:
                raise MeasuredDataError(
                    f"topic {topic!r}: message has no numeric field {missing[0]!r}; it has "
                    f"{', '.join(first)}"
                )
            sec = column(table, *first["header.stamp.sec"]).astype(float)
            nsec = column(table, *first["header.stamp.nanosec"]).astype(float)
            cols = {n: column(table, *first[path]).astype(float) for n, path in fields.items()}
            return log_ns, sec + nsec * 1e-9, cols
        datas = [row.tobytes() for row in table]
    else:
        assert raw.datas is not None
        datas = [raw.datas[i] for i in order]
    stamps_list: list[float] = []
    values_of: dict[str, list[float]] = {name: [] for name in fields}
    for data in datas:
        where = layout(data)
        for name, path in fields.items():
            if path not in where:
                raise MeasuredDataError(f"topic {topic!r}: message has no numeric field {path!r}")
            offset, code = where[path]
            values_of[name].append(float(np.frombuffer(data, code, 1, offset)[0]))
        sec = int(np.frombuffer(data, "<i4", 1, where["header.stamp.sec"][0])[0])
        nsec = int(np.frombuffer(data, "<u4", 1, where["header.stamp.nanosec"][0])[0])
        stamps_list.append(sec + nsec * 1e-9)
    return (
        log_ns,
        np.asarray(stamps_list),
        {name: np.asarray(v, dtype=float) for name, v in values_of.items()},
    )


def _decode_generic(
    bag: str | Path, topic: str, fields: dict[str, str]
) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Any message type, with the bag reader's generic decoder (slow, but complete)."""
    log: list[int] = []
    stamps: list[float] = []
    cols: dict[str, list[float]] = {name: [] for name in fields}
    for item in BagReader(bag).messages([topic]):
        msg = item.msg
        header = getattr(msg, "header", None)
        log.append(item.log_time_ns)
        stamps.append(
            header.stamp.sec + header.stamp.nanosec * 1e-9
            if header is not None
            else item.log_time_ns * 1e-9
        )
        values = {}
        for path in fields.values():
            name = path.partition("[")[0]
            values[name] = getattr(msg, name, None)
            if values[name] is None:
                del values[name]
        for name, path in fields.items():
            cols[name].append(_field(values, path, topic))
    return (
        np.asarray(log, dtype=np.int64),
        np.asarray(stamps, dtype=float),
        {name: np.asarray(v, dtype=float) for name, v in cols.items()},
    )


class MessageFields:
    """One message at a time (a live subscription): stamp [s] and the mapped signals in SI.

    The byte layout of a message is computed once per message size (the strings, and so the
    offsets, only change with it) and reused."""

    def __init__(
        self, type_name: str, signals: dict[str, tuple[str, ColumnSpec]], cmap: ColumnMap
    ) -> None:
        self.type_name = type_name
        self._codec = None if type_name == msg_types.JOINT_STATE else FlatCodec(type_name)
        self._paths = {name: col.partition(":")[2] for name, (col, _) in signals.items()}
        self._scale = {
            name: float(_to_si(name, spec, np.ones(1), cmap.conversion)[0])
            for name, (_, spec) in signals.items()
        }
        self._layouts: dict[int, dict[str, tuple[int, str]]] = {}

    @property
    def signal_names(self) -> tuple[str, ...]:
        """The mapped signals each message yields (pos_meas_m, pos_cmd_m, ...)."""
        return tuple(self._paths)

    def __call__(self, data: bytes) -> tuple[float, dict[str, float]]:
        where = self._layouts.get(len(data))
        if where is None:
            codec = self._codec
            where = _joint_state(data)[1] if codec is None else flat_offsets(codec, data)
            missing = [p for p in self._paths.values() if p not in where]
            if missing:
                raise MeasuredDataError(
                    f"{self.type_name}: message has no numeric field {missing[0]!r}"
                )
            self._layouts[len(data)] = where
        sec = struct.unpack_from("<i", data, where["header.stamp.sec"][0])[0]
        nsec = struct.unpack_from("<I", data, where["header.stamp.nanosec"][0])[0]
        values = {}
        for name, path in self._paths.items():
            offset, code = where[path]
            values[name] = float(np.frombuffer(data, code, 1, offset)[0]) * self._scale[name]
        return sec + nsec * 1e-9, values
