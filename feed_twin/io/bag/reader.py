"""`BagReader`: the messages of a finished bag decoded to Python objects (no rclpy)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from feed_twin.io.bag.layout import BagError, BagInfo, TopicInfo
from feed_twin.io.bag.metadata import info


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
        value becomes seconds as float64, strings stay as an object array.
        """
        values: dict[str, list] = {name: [] for name in fields}
        times: list[float] = []
        for item in self.messages([topic]):
            times.append(item.log_time_ns * 1e-9)
            for name in fields:
                values[name].append(_field_value(item.msg, name, topic))
        out: dict[str, np.ndarray] = {"log_time_s": np.asarray(times, dtype=float)}
        for name, column in values.items():
            if column and isinstance(column[0], str):
                out[name] = np.asarray(column, dtype=object)
            else:
                out[name] = np.asarray(column, dtype=float)
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
