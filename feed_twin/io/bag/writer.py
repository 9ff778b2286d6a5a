"""`BagWriter`: raw CDR messages into a new rosbag2 bag directory, flushed periodically."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from mcap.writer import CompressionType, Writer

from feed_twin.io.bag.layout import (
    MESSAGE_ENCODING,
    METADATA_FILE,
    PROFILE,
    ROS_DISTRO,
    SCHEMA_ENCODING,
    BagError,
    BagInfo,
    QosProfile,
    TopicInfo,
    qos_yaml,
)
from feed_twin.io.bag.metadata import info, metadata_yaml, write_atomically
from feed_twin.io.bag.schema import message_definition


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    qos_text: str
    type_hash: str
    count: int = 0


class BagWriter:
    """Write raw CDR messages into a new rosbag2 bag directory.

    `add_topic` registers a topic with its installed message type; `write` appends one
    serialised message. A background thread flushes every `flush_period_s` (None: only at
    `close`). Thread-safe: a recorder may write from several callbacks.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        flush_period_s: float | None = 0.5,
        compression: Literal["zstd", "none"] = "zstd",
    ) -> None:
        self.path = Path(path)
        if flush_period_s is not None and not (flush_period_s > 0.0):
            raise ValueError(f"flush_period_s = {flush_period_s!r}: must be > 0 or None")
        if self.path.exists() and any(self.path.iterdir()):
            raise BagError(f"{self.path}: the bag directory exists and is not empty")
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / f"{self.path.name}_0.mcap"
        self._file = open(self.mcap_path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(
            self._file,
            compression=CompressionType.ZSTD if compression == "zstd" else CompressionType.NONE,
        )
        self._writer.start(profile=PROFILE, library="feed_twin")
        self._topics: dict[str, _Topic] = {}
        self._schemas: dict[str, int] = {}
        self._start_ns: int | None = None
        self._end_ns = 0
        self._lock = threading.Lock()
        self._closed = False
        # Set when the file system refused a write (a full disk): the bag stops growing, what
        # was flushed before stays recoverable (`recover`), and the recorder reports it.
        self.error: str | None = None
        self.dropped = 0  # messages not written after the error
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None
        if flush_period_s is not None:
            self._flusher = threading.Thread(
                target=self._flush_loop, args=(flush_period_s,), name="bag-flush", daemon=True
            )
            self._flusher.start()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self._topics.values())

    def topic_names(self) -> tuple[str, ...]:
        return tuple(self._topics)

    def add_topic(
        self, name: str, type_name: str, *, qos: Sequence[QosProfile] | str = (QosProfile(),)
    ) -> None:
        """Register `name` with message type `pkg/msg/Type` before writing to it. `qos`: the
        offered profiles, or rosbag2's YAML text of them, kept verbatim (copied from a bag)."""
        if not name.startswith("/"):
            raise BagError(f"topic {name!r}: must be an absolute name starting with '/'")
        definition = message_definition(type_name)
        with self._lock:
            self._check_open()
            if name in self._topics:
                known = self._topics[name].type_name
                if known != type_name:
                    raise BagError(
                        f"topic {name!r} is already recorded as {known}, not {type_name}"
                    )
                return
            schema_id = self._schemas.get(type_name)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=type_name,
                    encoding=SCHEMA_ENCODING,
                    data=definition.schema_text.encode("utf-8"),
                )
                self._schemas[type_name] = schema_id
            qos_text = qos if isinstance(qos, str) else qos_yaml(qos)
            channel_id = self._writer.register_channel(
                topic=name,
                message_encoding=MESSAGE_ENCODING,
                schema_id=schema_id,
                metadata={
                    "offered_qos_profiles": qos_text,
                    "topic_type_hash": definition.type_hash,
                },
            )
            self._topics[name] = _Topic(
                name=name,
                type_name=type_name,
                channel_id=channel_id,
                qos_text=qos_text,
                type_hash=definition.type_hash,
            )

    def write(
        self, topic: str, data: bytes, *, log_time_ns: int, publish_time_ns: int | None = None
    ) -> None:
        """Append one CDR-serialised message (the exact wire bytes) to a registered topic."""
        with self._lock:
            self._check_open()
            entry = self._topics.get(topic)
            if entry is None:
                raise BagError(f"topic {topic!r} is not registered; call add_topic first")
            if self.error is not None:
                self.dropped += 1
                return
            try:
                self._writer.add_message(
                    channel_id=entry.channel_id,
                    log_time=log_time_ns,
                    publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
                    data=bytes(data),
                    sequence=entry.count,
                )
            except OSError as exc:
                self._fail(exc)
                return
            entry.count += 1
            if self._start_ns is None or log_time_ns < self._start_ns:
                self._start_ns = log_time_ns
            self._end_ns = max(self._end_ns, log_time_ns)

    def flush(self) -> None:
        """Finish the open chunk and hand everything written so far to the OS."""
        with self._lock:
            if not self._closed and self.error is None:
                try:
                    self._writer.flush()
                except OSError as exc:
                    self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        self.error = f"{exc.strerror or exc} writing {self.mcap_path}"
        with contextlib.suppress(OSError):
            self._file.close()

    def close(self) -> BagInfo:
        """Finish the MCAP file (summary, index, footer) and write metadata.yaml."""
        self._stop.set()
        if self._flusher is not None:
            self._flusher.join(timeout=5.0)
        with self._lock:
            if not self._closed and self.error is not None:
                self._closed = True
                raise BagError(f"{self.path}: recording stopped: {self.error}")
            if not self._closed:
                topics = [
                    TopicInfo(
                        name=t.name,
                        type_name=t.type_name,
                        message_count=t.count,
                        offered_qos_profiles=t.qos_text,
                        type_hash=t.type_hash,
                    )
                    for t in self._topics.values()
                ]
                start = self._start_ns or 0
                text = metadata_yaml(
                    mcap_name=self.mcap_path.name,
                    start_ns=start,
                    end_ns=max(self._end_ns, start),
                    topics=topics,
                )
                self._writer.add_metadata(
                    "rosbag2", {"serialized_metadata": text, "ROS_DISTRO": ROS_DISTRO}
                )
                self._closed = True
                try:
                    self._writer.finish()
                    self._file.close()
                    write_atomically(self.path / METADATA_FILE, text)
                except OSError as exc:
                    self._fail(exc)
                    raise BagError(f"{self.path}: closing the recording: {self.error}") from None
        return info(self.path)

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f"{self.path}: the bag is closed")

    def _flush_loop(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            try:
                self.flush()
            except (OSError, ValueError):
                return
