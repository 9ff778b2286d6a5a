"""Index a cut MCAP recording in place: keep every complete chunk, write no second copy.

A recording ends without its summary when its writer dies or its disk fills. What the writer
flushed is a run of complete records (chunks, each followed by its message indexes) and then,
perhaps, part of one record. `scan` walks the records with bounds checked at every field (a cut
may fall anywhere, inside a length, a string or a chunk's data), opens each chunk and checks
its CRC, and stops at the first record that is incomplete or does not read. `index_in_place`
then cuts the file there and appends what the writer would have written at its end: the
message indexes of the last chunk if they were cut, DataEnd, the summary (schemas, channels,
statistics, chunk indexes, summary offsets), the footer and the closing magic (MCAP spec,
"Summary Section"). The appended bytes are a few hundred per chunk, less than the partial
record the cut removes in most cases, so a full disk has room for them; when it does not, the
file is left as the cut made it (every complete chunk still there) and the error says so.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    MessageIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

MAGIC = b"\x89MCAP0\r\n"
RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
MESSAGE_HEAD = struct.Struct("<HIQ")  # a Message record's channel id, sequence, log time


class CutBagError(ValueError):
    """Nothing in the file can be kept, or the index cannot be written (one line)."""


@dataclass
class _ChunkFound:
    start: int  # offset of the chunk record
    end: int  # offset just past it
    record: Chunk
    messages: dict[int, list[tuple[int, int]]]  # channel -> [(log time, offset in chunk)]
    indexes: dict[int, int] = field(default_factory=dict)  # channel -> MessageIndex offset
    indexes_end: int = 0  # offset past its last complete MessageIndex


@dataclass
class Scan:
    """What a recording holds up to its first incomplete or unreadable record."""

    size: int  # [bytes] of the file
    kept_end: int  # [bytes] the complete records end here
    finished: bool  # the file has its footer and closing magic: nothing to do
    chunks: list[_ChunkFound] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)  # channel -> messages
    metadata_ends: list[int] = field(default_factory=list)  # offsets past Metadata records

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())


def scan(path: Path) -> Scan:
    """Walk the records of an MCAP file (module docstring)."""
    data = path.read_bytes()
    if not data.startswith(MAGIC):
        raise CutBagError(f"{path}: nothing recoverable: not an MCAP file (no magic at its start)")
    found = Scan(size=len(data), kept_end=len(MAGIC), finished=False)
    pos = len(MAGIC)
    while pos + RECORD_HEAD.size <= len(data):
        opcode, length = RECORD_HEAD.unpack_from(data, pos)
        end = pos + RECORD_HEAD.size + length
        if end > len(data):
            break
        content = data[pos + RECORD_HEAD.size : end]
        try:
            stop = _take(found, opcode, content, pos, end)
        except (struct.error, ValueError, UnicodeDecodeError, zstandard.ZstdError, EOFError):
            break  # a record that does not read (garbage where the cut fell): stop before it
        if stop:
            found.finished = data.endswith(MAGIC) and len(data) >= 2 * len(MAGIC)
            break
        found.kept_end = end
        pos = end
    return found


def _take(found: Scan, opcode: int, content: bytes, pos: int, end: int) -> bool:
    """Add one complete record to `found`; True at the data section's end."""
    if opcode == Opcode.CHUNK:
        chunk = Chunk.read(_stream(content))
        found.chunks.append(_ChunkFound(pos, end, chunk, _open_chunk(found, chunk)))
    elif opcode == Opcode.MESSAGE_INDEX:
        index = MessageIndex.read(_stream(content))
        if found.chunks:
            found.chunks[-1].indexes[index.channel_id] = pos
            found.chunks[-1].indexes_end = end
    elif opcode == Opcode.SCHEMA:
        schema = Schema.read(_stream(content))
        found.schemas[schema.id] = schema
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(_stream(content))
        found.channels[channel.id] = channel
    elif opcode == Opcode.METADATA:
        found.metadata_ends.append(end)  # rosbag2's, written when the recording closes
    elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
        return True
    return False


def _stream(content: bytes) -> ReadDataStream:
    return ReadDataStream(io.BytesIO(content))


def _open_chunk(found: Scan, chunk: Chunk) -> dict[int, list[tuple[int, int]]]:
    """The chunk's messages per channel (its schemas and channels go into `found`); raises
    ValueError when its data does not decompress to what its header says."""
    if chunk.compression == "zstd":
        data = zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"compression {chunk.compression!r} is not read here")
    if len(data) != chunk.uncompressed_size:
        raise ValueError("the chunk's size differs from its header")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("the chunk's CRC differs")
    messages: dict[int, list[tuple[int, int]]] = {}
    schemas, channels, counts = {}, {}, {}
    pos = 0
    while pos < len(data):
        opcode, length = RECORD_HEAD.unpack_from(data, pos)
        content = data[pos + RECORD_HEAD.size : pos + RECORD_HEAD.size + length]
        if len(content) != length:
            raise ValueError("a record runs past the chunk's end")
        if opcode == Opcode.MESSAGE:
            channel_id, _, log_time = MESSAGE_HEAD.unpack_from(content)
            messages.setdefault(channel_id, []).append((log_time, pos))
            counts[channel_id] = counts.get(channel_id, 0) + 1
        elif opcode == Opcode.SCHEMA:
            schema = Schema.read(_stream(content))
            schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(_stream(content))
            channels[channel.id] = channel
        pos += RECORD_HEAD.size + length
    # only a chunk that read whole counts
    found.schemas.update(schemas)
    found.channels.update(channels)
    for channel_id, n in counts.items():
        found.counts[channel_id] = found.counts.get(channel_id, 0) + n
    return messages


@dataclass(frozen=True, kw_only=True)
class Indexed:
    """What `index_in_place` kept."""

    messages: int
    chunks: int
    kept_bytes: int  # of the data the writer flushed
    dropped_bytes: int  # the incomplete record at the end
    finished: bool  # the file had its footer already: nothing was changed


def index_in_place(path: Path) -> tuple[Indexed, Scan]:
    """Cut the file after its last complete record and append its summary (module
    docstring); returns what was kept and what the scan found. Raises CutBagError when no
    chunk is complete, or when the file system has no
    room for the summary (the file then ends after its last complete record)."""
    found = scan(path)
    if found.finished:
        done = Indexed(
            messages=found.message_count, chunks=len(found.chunks), kept_bytes=found.size,
            dropped_bytes=0, finished=True,
        )  # fmt: skip
        return done, found
    if not found.chunks or not found.channels:
        raise CutBagError(
            f"{path}: nothing recoverable: no complete chunk in its {found.size} bytes"
        )
    last = found.chunks[-1]
    complete_indexes = set(last.indexes) >= set(last.messages)
    # everything complete after the last chunk (its indexes, a Metadata record) is kept,
    # unless the last chunk's message indexes were cut: then they are written again
    keep = found.kept_end if complete_indexes else last.end
    tail = _tail(found, keep, rebuild_last=not complete_indexes)
    fd = os.open(path, os.O_RDWR)
    try:
        os.ftruncate(fd, keep)
        try:
            written = 0
            while written < len(tail):  # unbuffered: a refused write is seen here, not later
                written += os.pwrite(fd, tail[written:], keep + written)
            os.fsync(fd)
        except OSError as exc:
            os.ftruncate(fd, keep)
            raise CutBagError(
                f"{path}: no room to index the recording in place ({exc.strerror}; "
                f"{len(tail)} bytes needed): its {len(found.chunks)} complete chunks "
                f"({found.message_count} messages) are kept as they are; free some space "
                "and run `feed-twin bag recover` on it"
            ) from None
    finally:
        os.close(fd)
    indexed = Indexed(
        messages=found.message_count,
        chunks=len(found.chunks),
        kept_bytes=keep,
        dropped_bytes=found.size - keep,
        finished=False,
    )
    return indexed, found


def _tail(found: Scan, keep: int, *, rebuild_last: bool) -> bytes:
    """The bytes that finish the file after offset `keep`."""
    data = RecordBuilder()
    indexes: list[ChunkIndex] = []
    for k, chunk in enumerate(found.chunks):
        at, length = dict(chunk.indexes), chunk.indexes_end - chunk.end
        if rebuild_last and k == len(found.chunks) - 1:
            at, start = {}, keep + data.count
            for channel_id, records in sorted(chunk.messages.items()):
                at[channel_id] = keep + data.count
                MessageIndex(channel_id, records).write(data)
            length = keep + data.count - start
        indexes.append(
            ChunkIndex(
                message_start_time=chunk.record.message_start_time,
                message_end_time=chunk.record.message_end_time,
                chunk_start_offset=chunk.start,
                chunk_length=chunk.end - chunk.start,
                message_index_offsets=at,
                message_index_length=max(length, 0),
                compression=chunk.record.compression,
                compressed_size=len(chunk.record.data),
                uncompressed_size=chunk.record.uncompressed_size,
            )
        )
    DataEnd(data_section_crc=0).write(data)  # 0: not computed (MCAP spec)
    summary_start = keep + data.count
    summary = RecordBuilder()
    offsets: list[SummaryOffset] = []
    groups = (
        (Opcode.SCHEMA, list(found.schemas.values())),
        (Opcode.CHANNEL, list(found.channels.values())),
        (Opcode.STATISTICS, [_statistics(found, keep)]),
        (Opcode.CHUNK_INDEX, indexes),
    )
    for opcode, records in groups:
        start = summary.count
        for record in records:
            record.write(summary)
        offsets.append(SummaryOffset(opcode, summary_start + start, summary.count - start))
    summary_offset_start = summary_start + summary.count
    for offset in offsets:
        offset.write(summary)
    body = summary.end()
    crc = zlib.crc32(
        struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start),
        zlib.crc32(body),
    )
    footer = RecordBuilder()
    Footer(summary_start, summary_offset_start, crc).write(footer)
    return data.end() + body + footer.end() + MAGIC


def _statistics(found: Scan, keep: int) -> Statistics:
    chunks = [c.record for c in found.chunks]
    return Statistics(
        message_count=found.message_count,
        schema_count=len(found.schemas),
        channel_count=len(found.channels),
        attachment_count=0,
        metadata_count=sum(end <= keep for end in found.metadata_ends),
        chunk_count=len(chunks),
        message_start_time=min(c.message_start_time for c in chunks),
        message_end_time=max(c.message_end_time for c in chunks),
        channel_message_counts=dict(found.counts),
    )
