"""Recovery of a killed recording (`recover`) and topics added to a finished bag (`add_topics`)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from feed_twin.io.bag.index import CutBagError, index_in_place
from feed_twin.io.bag.layout import (
    MESSAGE_ENCODING,
    METADATA_FILE,
    PROFILE,
    ROS_DISTRO,
    SCHEMA_ENCODING,
    BagError,
    BagInfo,
    QosProfile,
    bag_paths,
    qos_yaml,
)
from feed_twin.io.bag.metadata import info, metadata_yaml, topic_infos, write_atomically
from feed_twin.io.bag.schema import message_definition


@dataclass(frozen=True, kw_only=True)
class RecoverResult:
    info: BagInfo
    messages_recovered: int
    was_complete: bool  # the file already had a valid footer
    chunks: int = 0  # complete chunks kept
    kept_bytes: int = 0  # [bytes] of the file as the writer flushed it
    dropped_bytes: int = 0  # [bytes] the incomplete record at the end, cut off

    def text(self) -> str:
        """How much was kept, for a person."""
        if self.was_complete:
            return f"the recording was complete: {self.messages_recovered} messages"
        dropped = (
            f"the last {self.dropped_bytes} bytes, an incomplete record, dropped"
            if self.dropped_bytes
            else "nothing after them"
        )
        return (
            f"recovered {self.messages_recovered} messages in {self.chunks} complete chunks "
            f"({self.kept_bytes} bytes kept, {dropped}); indexed in place"
        )


def recover(path: str | Path) -> RecoverResult:
    """Make a cut recording readable: every complete chunk is kept and the file is indexed in
    place (feed_twin.io.bag.index), never copied, so a full disk loses nothing that was
    flushed; metadata.yaml is written again. Raises BagError (one line) when nothing can be
    kept or there is no room for the index (the file is then left as flushed)."""
    directory, mcap_path = bag_paths(path)
    try:
        indexed, found = index_in_place(mcap_path)
    except CutBagError as exc:
        raise BagError(str(exc)) from None
    except OSError as exc:
        raise BagError(f"{mcap_path}: cannot read or index it ({exc.strerror})") from None
    chunks = [c.record for c in found.chunks]
    text = metadata_yaml(
        mcap_name=mcap_path.name,
        start_ns=min((c.message_start_time for c in chunks), default=0),
        end_ns=max((c.message_end_time for c in chunks), default=0),
        topics=topic_infos(found.channels, found.schemas, found.counts),
    )
    try:
        write_atomically(directory / METADATA_FILE, text)
    except OSError as exc:
        raise BagError(
            f"{directory / METADATA_FILE}: cannot write it ({exc.strerror}); the recording "
            f"itself is indexed ({indexed.messages} messages kept)"
        ) from None
    return RecoverResult(
        info=info(directory),
        messages_recovered=indexed.messages,
        was_complete=indexed.finished,
        chunks=indexed.chunks,
        kept_bytes=indexed.kept_bytes,
        dropped_bytes=indexed.dropped_bytes,
    )


def add_topics(
    path: str | Path, topics: dict[str, tuple[str, Sequence[tuple[int, bytes]]]]
) -> BagInfo:
    """Rewrite a finished bag with more topics: name -> (message type, [(log time ns, CDR
    bytes)]), for figures computed after the run (a machine run's contour error). The original
    is replaced once the new file is complete on disk."""
    directory, mcap_path = bag_paths(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    with open(mcap_path, "rb") as f:
        for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                messages.append(record)
    for name, (type_name, items) in topics.items():
        if any(c.topic == name for c in channels.values()):
            raise BagError(f"{directory}: topic {name!r} is already in the bag")
        definition = message_definition(type_name)
        schema_id = next((i for i, s in schemas.items() if s.name == type_name), None)
        if schema_id is None:
            schema_id = max(schemas, default=0) + 1
            schemas[schema_id] = Schema(
                id=schema_id,
                name=type_name,
                encoding=SCHEMA_ENCODING,
                data=definition.schema_text.encode("utf-8"),
            )
        channel_id = max(channels, default=0) + 1
        channels[channel_id] = Channel(
            id=channel_id,
            schema_id=schema_id,
            topic=name,
            message_encoding=MESSAGE_ENCODING,
            metadata={
                "offered_qos_profiles": qos_yaml((QosProfile(),)),
                "topic_type_hash": definition.type_hash,
            },
        )
        messages += [
            Message(channel_id=channel_id, sequence=k, log_time=t, publish_time=t, data=data)
            for k, (t, data) in enumerate(items)
        ]
    tmp = mcap_path.with_name(mcap_path.name + ".adding")
    text, _ = _write_recovered(tmp, schemas, channels, messages, mcap_path.name)
    os.replace(tmp, mcap_path)
    write_atomically(directory / METADATA_FILE, text)
    return info(directory)


def _write_recovered(target: Path, schemas, channels, messages, mcap_name: str):
    """Write the recovered records to `target` (synced); returns (metadata text, counts)."""
    counts: dict[int, int] = dict.fromkeys(channels, 0)
    with open(target, "wb") as out:
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile=PROFILE, library="feed_twin recover")
        schema_ids = {
            sid: writer.register_schema(name=s.name, encoding=s.encoding, data=s.data)
            for sid, s in schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(
                topic=c.topic,
                message_encoding=c.message_encoding,
                schema_id=schema_ids.get(c.schema_id, 0),
                metadata=dict(c.metadata),
            )
            for cid, c in channels.items()
        }
        messages.sort(key=lambda m: m.log_time)
        for m in messages:
            if m.channel_id not in channel_ids:
                continue
            writer.add_message(
                channel_id=channel_ids[m.channel_id],
                log_time=m.log_time,
                publish_time=m.publish_time,
                data=m.data,
                sequence=m.sequence,
            )
            counts[m.channel_id] += 1
        topics = topic_infos(channels, schemas, counts)
        start = messages[0].log_time if messages else 0
        end = messages[-1].log_time if messages else 0
        text = metadata_yaml(mcap_name=mcap_name, start_ns=start, end_ns=end, topics=topics)
        writer.add_metadata("rosbag2", {"serialized_metadata": text, "ROS_DISTRO": ROS_DISTRO})
        writer.finish()
        out.flush()
        os.fsync(out.fileno())
    return text, counts
