"""Messages of a finished bag as raw CDR bytes, fast, and numeric fields read at byte offsets.

The mcap package parses each record in Python (about 10 us a message) and mcap_ros2 decodes
each message field by field (tens of us more); a run beside LinuxCNC records five messages a
servo period, 300 000 a minute, so reading a few topics back that way took minutes after every
run. `raw_messages` decompresses each chunk once and takes the messages of the wanted topics
with the bag's message indexes; `column` reads one numeric field of a whole table of messages
of one size and layout at once (its offset: `flat_offsets` for a flat message, or the
message's own layout).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from mcap.reader import make_reader

from feed_twin.io.bag.layout import BagError

if TYPE_CHECKING:
    from feed_twin.io.cdr import FlatCodec


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
                raise BagError(f"{mcap_path}: no chunk at offset {index.chunk_start_offset}")
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
    raise BagError(f"{source}: chunk compression {compression!r} is not supported")


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


def column(table: np.ndarray, offset: int, code: str) -> np.ndarray:
    dtype = np.dtype(code)
    return np.ascontiguousarray(table[:, offset : offset + dtype.itemsize]).view(dtype)[:, 0]


def uniform_offsets(codec: FlatCodec, table: np.ndarray) -> dict[str, tuple[int, str]] | None:
    """`flat_offsets` of the messages in the rows of `table` (n >= 1, one size) when every
    row has the layout of the first (each string as long as the first row's), else None."""
    first = table[0].tobytes()
    values = codec.decode(first)
    offset = 0
    for (_, kind), value in zip(codec.fields, values, strict=True):
        if kind == "string":
            offset += -offset % 4
            # the strings before this one are as long in every row: so is its length's offset
            lengths = column(table, 4 + offset, "<u4")
            if np.any(lengths != lengths[0]):
                return None
            offset += 4 + len(value.encode("utf-8")) + 1
        else:
            size = np.dtype(_NUMPY[kind]).itemsize
            offset += -offset % size + size
    return flat_offsets(codec, first)
