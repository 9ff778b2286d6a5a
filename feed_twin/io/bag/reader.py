"""`BagReader`: the messages of a finished bag decoded to Python objects (no rclpy)."""

from __future__ import annotations

import struct
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from feed_twin.io.bag.layout import BagError, BagInfo, TopicInfo
from feed_twin.io.bag.metadata import info
from feed_twin.io.bag.raw import column, raw_messages, uniform_offsets


@dataclass(frozen=True, kw_only=True)
class BagMessage:
    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    msg: Any  # decoded message: attributes named as in the .msg file


@dataclass
class BagReader:
    """Decode the messages of a finished bag to Python objects (no rclpy needed)."""

    path: Path
    info: BagInfo = field(init=False)

    def __init__(self, path: str | Path) -> None:
        self.info = info(path)
        self.path = self.info.path

    def topic(self, name: str) -> TopicInfo:
        for t in self.info.topics:
            if t.name == name:
                return t
        known = ", ".join(t.name for t in self.info.topics) or "none"
        raise BagError(f"{self.path}: no topic {name!r} in the bag (topics: {known})")

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
        """Decoded messages of `topics` (all when None) in log-time order."""
        if topics is not None:
            for name in topics:
                self.topic(name)
        with open(self.info.mcap_path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=list(topics) if topics is not None else None, log_time_order=True
            ):
                yield BagMessage(
                    topic=channel.topic,
                    type_name=schema.name if schema else "",
                    log_time_ns=message.log_time,
                    publish_time_ns=message.publish_time,
                    msg=decoded,
                )

    def columns(self, topic: str, fields: Sequence[str]) -> dict[str, np.ndarray]:
        """Arrays of the named fields of every message on `topic`, plus `log_time_s`.

        A field is a dotted path (`header.stamp`, `position[0]`); a builtin_interfaces/Time
        value becomes seconds as float64, strings stay as an object array. Numbers of a flat
        message type whose messages share one layout are read at their byte offsets
        (feed_twin.io.bag.raw), anything else through the message decoder.
        """
        fast = self._flat_columns(topic, fields)
        if fast is not None:
            return fast
        values: dict[str, list] = {name: [] for name in fields}
        log_ns, messages = self._decoded(topic)
        for msg in messages:
            for name in fields:
                values[name].append(_field_value(msg, name, topic))
        out: dict[str, np.ndarray] = {"log_time_s": np.asarray(log_ns, dtype=float) * 1e-9}
        for name, taken in values.items():
            if taken and isinstance(taken[0], str):
                out[name] = np.asarray(taken, dtype=object)
            else:
                out[name] = np.asarray(taken, dtype=float)
        return out

    def _decoded(self, topic: str) -> tuple[np.ndarray | list[int], list[Any]]:
        """Log times [ns] and decoded messages of `topic` in log-time order: the messages taken
        by the bag's index (feed_twin.io.bag.raw), not by parsing every record of the file."""
        self.topic(topic)
        with open(self.info.mcap_path, "rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None or not summary.chunk_indexes:
            items = list(self.messages([topic]))
            return [i.log_time_ns for i in items], [i.msg for i in items]
        channel = next(c for c in summary.channels.values() if c.topic == topic)
        decode = DecoderFactory().decoder_for(
            channel.message_encoding, summary.schemas.get(channel.schema_id)
        )
        if decode is None:
            raise BagError(f"{self.path}: {topic}: no decoder for {channel.message_encoding!r}")
        raw = raw_messages(self.info.mcap_path, {topic})[topic]
        datas = [row.tobytes() for row in raw.table] if raw.table is not None else raw.datas or []
        order = np.argsort(raw.log_time_ns, kind="stable")
        return raw.log_time_ns[order], [decode(datas[i]) for i in order]

    def _flat_columns(self, topic: str, fields: Sequence[str]) -> dict[str, np.ndarray] | None:
        """`columns` read at byte offsets, or None: not a flat type, messages of several
        layouts or none, or a field that is not a number (the decoder's path says why)."""
        # (imported here: feed_twin.io.cdr reads message definitions through this package)
        from feed_twin.io.cdr import FlatCodec, NotFlatError

        try:
            codec = FlatCodec(self.topic(topic).type_name)
        except (NotFlatError, LookupError):
            return None
        raw = raw_messages(self.info.mcap_path, {topic})[topic]
        if raw.table is None or not len(raw.table):
            return None
        order = np.argsort(raw.log_time_ns, kind="stable")  # log-time order, as `messages`
        table = raw.table[order]
        try:
            where = uniform_offsets(codec, table)
        except (ValueError, struct.error):  # not what FlatCodec reads: the decoder's business
            where = None
        if where is None:
            return None
        out = {"log_time_s": raw.log_time_ns[order] * 1e-9}
        for name in fields:
            if name in where:
                out[name] = column(table, *where[name]).astype(float)
            elif f"{name}.sec" in where and f"{name}.nanosec" in where:
                sec = column(table, *where[f"{name}.sec"]).astype(float)
                out[name] = sec + column(table, *where[f"{name}.nanosec"]) * 1e-9
            else:
                return None
        return out


def _field_value(msg: Any, path: str, topic: str) -> Any:
    value = msg
    for part in path.split("."):
        index = None
        if part.endswith("]") and "[" in part:
            part, _, rest = part.partition("[")
            index = int(rest[:-1])
        if not hasattr(value, part):
            raise BagError(f"topic {topic!r}: message has no field {path!r} (at {part!r})")
        value = getattr(value, part)
        if index is not None:
            try:
                value = value[index]
            except IndexError:
                raise BagError(
                    f"topic {topic!r}: field {path!r} has {len(value)} entries, no [{index}]"
                ) from None
    if hasattr(value, "sec") and hasattr(value, "nanosec"):
        return value.sec + value.nanosec * 1e-9
    return value
