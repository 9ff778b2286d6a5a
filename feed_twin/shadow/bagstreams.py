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
from mcap.reader import make_reader

from feed_twin.io import msg_types
from feed_twin.io.bag import BagReader, info
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


def flat_offsets(codec: FlatCodec, data: bytes) -> dict[str, tuple[int, str]]:
    """(byte offset in `data`, numpy code) of each numeric field of a flat message, laid out
    as in `data` (its strings fix the offsets of what follows them)."""
    values = codec.decode(data)
    where: dict[str, tuple[int, str]] = {}
    offset = 0
    for (name, kind), value in zip(codec.fields, values, strict=True):
        if kind == "string":
            offset += -offset % 4
            offset += 4 + len(value.encode("utf-8")) + 1
            continue
        code = _NUMPY[kind]
        size = np.dtype(code).itemsize
        offset += -offset % size
        where[name] = (4 + offset, code)
        offset += size
    return where


_NUMPY = {
    "bool": "?",
    "byte": "u1",
    "char": "u1",
    "int8": "i1",
    "uint8": "u1",
    "int16": "<i2",
    "uint16": "<u2",
    "int32": "<i4",
    "uint32": "<u4",
    "int64": "<i8",
    "uint64": "<u8",
    "float32": "<f4",
    "float64": "<f8",
}


def _column(table: np.ndarray, offset: int, code: str) -> np.ndarray:
    dtype = np.dtype(code)
    return np.ascontiguousarray(table[:, offset : offset + dtype.itemsize]).view(dtype)[:, 0]


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
    collected = raw_messages(bag_info.mcap_path, fast) if fast else {}
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


_CHUNK_OPCODE = 0x06
_MESSAGE_INDEX_OPCODE = 0x07


@dataclass(frozen=True, kw_only=True, eq=False)
class RawTopic:
    """The messages of one topic: log times [ns] and CDR bytes, as a table when all messages
    have one size (rows of `table`), else as a list (`datas`)."""

    log_time_ns: np.ndarray
    table: np.ndarray | None  # (n, size) uint8
    datas: list[bytes] | None


def raw_messages(mcap_path: Path, topics: set[str]) -> dict[str, RawTopic]:
    """Every message on `topics`, in file order.

    The mcap package parses each record in Python (about 10 us a message), and a replay reads
    120 000 messages a minute of a 1 kHz axis. A finished bag has a summary with a chunk index
    and, per chunk and channel, a message index (log time, offset of each message): with them
    each chunk is decompressed once and the messages of one size are gathered with numpy.
    A file without that index goes through the mcap reader.
    """
    logs: dict[str, list[np.ndarray]] = {t: [] for t in topics}
    parts: dict[str, list[np.ndarray | list[bytes]]] = {t: [] for t in topics}
    with open(mcap_path, "rb") as f:
        summary = make_reader(f).get_summary()
        if summary is None or not summary.chunk_indexes:
            return _raw_messages_slow(mcap_path, topics)
        channels = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in topics}
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(index.chunk_start_offset)
            opcode, length = struct.unpack("<BQ", f.read(9))
            if opcode != _CHUNK_OPCODE:
                raise MeasuredDataError(
                    f"{mcap_path}: no chunk at offset {index.chunk_start_offset}"
                )
            records = np.frombuffer(_chunk_records(f.read(length), mcap_path), dtype=np.uint8)
            for cid, topic in channels.items():
                where = index.message_index_offsets.get(cid)
                if where is None:
                    continue
                f.seek(where)
                opcode, length = struct.unpack("<BQ", f.read(9))
                entries = np.frombuffer(f.read(length)[6:], dtype="<u8").reshape(-1, 2)
                if opcode != _MESSAGE_INDEX_OPCODE or not len(entries):
                    continue
                offsets = entries[:, 1].astype(np.int64)
                record_length = _gather(records, offsets + 1, 8).view("<u8")[:, 0].astype(np.int64)
                data_start = offsets + 9 + 22
                data_length = record_length - 22
                logs[topic].append(entries[:, 0].astype(np.int64))
                if np.all(data_length == data_length[0]):
                    parts[topic].append(_gather(records, data_start, int(data_length[0])))
                else:
                    raw = records.tobytes()
                    spans = zip(data_start.tolist(), data_length.tolist(), strict=True)
                    parts[topic].append([raw[a : a + n] for a, n in spans])
    out: dict[str, RawTopic] = {}
    for topic in topics:
        log = np.concatenate(logs[topic]) if logs[topic] else np.zeros(0, dtype=np.int64)
        chunks = parts[topic]
        tables = [p for p in chunks if isinstance(p, np.ndarray)]
        if len(tables) == len(chunks) and len({t.shape[1] for t in tables}) <= 1:
            table = np.concatenate(tables) if tables else np.zeros((0, 0), dtype=np.uint8)
            out[topic] = RawTopic(log_time_ns=log, table=table, datas=None)
        else:
            datas: list[bytes] = []
            for p in chunks:
                datas += [row.tobytes() for row in p] if isinstance(p, np.ndarray) else p
            out[topic] = RawTopic(log_time_ns=log, table=None, datas=datas)
    return out


def _gather(records: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    return records[starts[:, None] + np.arange(width)[None, :]]


def _raw_messages_slow(mcap_path: Path, topics: set[str]) -> dict[str, RawTopic]:
    logs: dict[str, list[int]] = {t: [] for t in topics}
    datas: dict[str, list[bytes]] = {t: [] for t in topics}
    with open(mcap_path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=sorted(topics)):
            logs[channel.topic].append(message.log_time)
            datas[channel.topic].append(message.data)
    return {
        t: RawTopic(log_time_ns=np.asarray(logs[t], dtype=np.int64), table=None, datas=datas[t])
        for t in topics
    }


def _chunk_records(chunk: bytes, source: Path) -> bytes:
    _, _, size, _, name_length = struct.unpack_from("<QQQII", chunk, 0)
    offset = 32
    compression = chunk[offset : offset + name_length].decode("utf-8")
    offset += name_length
    (data_length,) = struct.unpack_from("<Q", chunk, offset)
    data = chunk[offset + 8 : offset + 8 + data_length]
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise MeasuredDataError(f"{source}: chunk compression {compression!r} is not supported")


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
            sec = _column(table, *first["header.stamp.sec"]).astype(float)
            nsec = _column(table, *first["header.stamp.nanosec"]).astype(float)
            cols = {n: _column(table, *first[path]).astype(float) for n, path in fields.items()}
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
