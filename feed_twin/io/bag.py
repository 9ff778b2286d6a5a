"""rosbag2-layout MCAP recordings: write raw CDR bytes, read back decoded, inspect, recover.

A bag is a directory holding `metadata.yaml` (rosbag2 version 9) and one `<name>_0.mcap` file
in the `ros2` profile: `ros2msg` schemas with their dependency blocks (`bag_schema`), `cdr`
message encoding, channel metadata `offered_qos_profiles` and `topic_type_hash`, log time =
receive time and publish time = send time in nanoseconds. ROS 2 tools, `rosbags` and Rerun read
it as a normal rosbag2 recording.

Crash safety: `BagWriter` finishes the open MCAP chunk and flushes it to the OS every
`flush_period_s` from a background thread, so a SIGKILL loses at most that period. Such a file
has no footer; `recover` streams its records with a non-seeking reader, rewrites every complete
message into a valid file and regenerates `metadata.yaml`.

`BagReader` decodes messages to Python objects with the `mcap_ros2` decoder (no rclpy), for
analysis and the discrepancy workflow; `BagReader.columns` returns numpy arrays of fields.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

from feed_twin.io.bag_schema import message_definition

ROSBAG2_VERSION = 9
ROS_DISTRO = "jazzy"
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
METADATA_FILE = "metadata.yaml"
# rmw's "infinite" duration as rosbag2 writes it: INT64_MAX nanoseconds split into sec/nsec.
_INFINITE_SEC = 9223372036
_INFINITE_NSEC = 854775807


class BagError(RuntimeError):
    """A bag cannot be opened, written, read or recovered; the message says which and why."""


@dataclass(frozen=True, kw_only=True)
class QosProfile:
    """The QoS a publisher offered, as rosbag2 stores it per topic (durations in seconds)."""

    history: Literal["keep_last", "keep_all", "system_default", "unknown"] = "keep_last"
    depth: int = 10
    reliability: Literal["reliable", "best_effort", "system_default", "unknown"] = "reliable"
    durability: Literal["volatile", "transient_local", "system_default", "unknown"] = "volatile"
    liveliness: Literal["automatic", "manual_by_topic", "system_default", "unknown"] = "automatic"
    deadline_s: float = math.inf  # [s]
    lifespan_s: float = math.inf  # [s]
    liveliness_lease_duration_s: float = math.inf  # [s]
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.depth, bool) or not isinstance(self.depth, int) or self.depth < 0:
            raise ValueError(f"depth = {self.depth!r}: must be a whole number >= 0")
        for name in ("deadline_s", "lifespan_s", "liveliness_lease_duration_s"):
            value = getattr(self, name)
            if math.isnan(value) or value < 0.0:
                raise ValueError(f"{name} = {value!r}: must be >= 0 (inf for none)")

    def to_dict(self) -> dict[str, Any]:
        def duration(seconds: float) -> dict[str, int]:
            if math.isinf(seconds):
                return {"sec": _INFINITE_SEC, "nsec": _INFINITE_NSEC}
            ns = round(seconds * 1e9)
            return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}

        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": duration(self.deadline_s),
            "lifespan": duration(self.lifespan_s),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": duration(self.liveliness_lease_duration_s),
            "avoid_ros_namespace_conventions": self.avoid_ros_namespace_conventions,
        }


def qos_yaml(profiles: Sequence[QosProfile]) -> str:
    """rosbag2's text form of a topic's offered QoS profiles (a YAML list)."""
    return yaml.safe_dump([p.to_dict() for p in profiles], sort_keys=False).rstrip("\n")


@dataclass(frozen=True, kw_only=True)
class TopicInfo:
    name: str
    type_name: str  # pkg/msg/Type
    message_count: int
    offered_qos_profiles: str = ""  # rosbag2 YAML text
    type_hash: str = ""  # RIHS01_...


@dataclass(frozen=True, kw_only=True)
class BagInfo:
    path: Path  # the bag directory
    mcap_path: Path
    start_ns: int  # first log time [ns since the epoch of the recording's clock]
    end_ns: int  # last log time [ns]
    message_count: int
    topics: tuple[TopicInfo, ...]

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    def format(self) -> str:
        width = max((len(t.name) for t in self.topics), default=5)
        type_width = max((len(t.type_name) for t in self.topics), default=4)
        lines = [
            f"bag:       {self.path}",
            f"file:      {self.mcap_path.name} ({self.mcap_path.stat().st_size} bytes)",
            f"duration:  {self.duration_s:.6f} s",
            f"start:     {self.start_ns * 1e-9:.9f} s",
            f"end:       {self.end_ns * 1e-9:.9f} s",
            f"messages:  {self.message_count}",
            f"topics:    {len(self.topics)}",
        ]
        for t in self.topics:
            lines.append(
                f"  {t.name:<{width}}  {t.type_name:<{type_width}}  {t.message_count:>9} msgs"
            )
        return "\n".join(lines)


@dataclass
class _Topic:
    name: str
    type_name: str
    channel_id: int
    qos_text: str
    type_hash: str
    count: int = 0


def bag_paths(path: str | Path) -> tuple[Path, Path]:
    """(bag directory, its .mcap file) for a bag directory or an .mcap path inside one."""
    path = Path(path)
    if path.suffix == ".mcap":
        if not path.is_file():
            raise BagError(f"{path}: no such file")
        return path.parent, path
    if not path.is_dir():
        raise BagError(f"{path}: no such bag directory")
    meta = path / METADATA_FILE
    if meta.is_file():
        try:
            data = yaml.safe_load(meta.read_text(encoding="utf-8"))
            files = data["rosbag2_bagfile_information"]["relative_file_paths"]
            candidate = path / files[0]
            if candidate.is_file():
                return path, candidate
        except (yaml.YAMLError, KeyError, TypeError, IndexError):
            pass
    found = sorted(path.glob("*.mcap"))
    if len(found) != 1:
        what = "no .mcap file" if not found else f"{len(found)} .mcap files"
        raise BagError(f"{path}: expected one .mcap file in the bag directory, found {what}")
    return path, found[0]


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
                    _write_atomically(self.path / METADATA_FILE, text)
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


def metadata_yaml(
    *, mcap_name: str, start_ns: int, end_ns: int, topics: Sequence[TopicInfo]
) -> str:
    """The rosbag2 (version 9) metadata.yaml text for one MCAP file."""
    count = sum(t.message_count for t in topics)
    duration = max(0, end_ns - start_ns)
    info_map = {
        "version": ROSBAG2_VERSION,
        "storage_identifier": "mcap",
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start_ns},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.type_name,
                    "serialization_format": MESSAGE_ENCODING,
                    "offered_qos_profiles": t.offered_qos_profiles,
                    "type_description_hash": t.type_hash,
                },
                "message_count": t.message_count,
            }
            for t in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [mcap_name],
        "files": [
            {
                "path": mcap_name,
                "starting_time": {"nanoseconds_since_epoch": start_ns},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": {},
        "ros_distro": ROS_DISTRO,
    }
    return yaml.safe_dump({"rosbag2_bagfile_information": info_map}, sort_keys=False)


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _topic_infos(channels: dict[int, Channel], schemas: dict[int, Schema], counts: dict) -> list:
    topics = []
    for channel_id, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        topics.append(
            TopicInfo(
                name=channel.topic,
                type_name=schema.name if schema else "",
                message_count=int(counts.get(channel_id, 0)),
                offered_qos_profiles=channel.metadata.get("offered_qos_profiles", ""),
                type_hash=channel.metadata.get("topic_type_hash", ""),
            )
        )
    return topics


def info(path: str | Path) -> BagInfo:
    """Topics, types, counts and time span of a finished bag, from the MCAP summary."""
    directory, mcap_path = bag_paths(path)
    with open(mcap_path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except (McapError, EOFError, ValueError) as exc:
            raise BagError(
                f"{mcap_path}: unreadable MCAP ({exc}); if the recording was killed, run "
                f"`feed-twin bag recover {directory}`"
            ) from None
    if summary is None or summary.statistics is None:
        raise BagError(
            f"{mcap_path}: the MCAP file has no summary (unfinished recording?); run "
            f"`feed-twin bag recover {directory}`"
        )
    stats = summary.statistics
    topics = _topic_infos(summary.channels, summary.schemas, stats.channel_message_counts)
    return BagInfo(
        path=directory,
        mcap_path=mcap_path,
        start_ns=stats.message_start_time,
        end_ns=stats.message_end_time,
        message_count=stats.message_count,
        topics=tuple(topics),
    )


@dataclass(frozen=True, kw_only=True)
class RecoverResult:
    info: BagInfo
    messages_recovered: int
    was_complete: bool  # the file already had a valid footer


def recover(path: str | Path) -> RecoverResult:
    """Make a killed recording readable: keep every complete message, rewrite, re-index.

    The original file is replaced only after the rewritten one is complete on disk.
    """
    directory, mcap_path = bag_paths(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    complete = False
    with open(mcap_path, "rb") as f:
        reader = StreamReader(f, skip_magic=False, emit_chunks=False, validate_crcs=True)
        try:
            for record in reader.records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    messages.append(record)
                if isinstance(record, Footer):
                    complete = True
        except (McapError, EOFError, ValueError, KeyError) as exc:
            if not messages and not channels:
                raise BagError(
                    f"{mcap_path}: nothing recoverable ({type(exc).__name__}: {exc})"
                ) from None
    if not channels:
        raise BagError(f"{mcap_path}: nothing recoverable (no channel records)")
    tmp = mcap_path.with_name(mcap_path.name + ".recovering")
    try:
        text, counts = _write_recovered(tmp, schemas, channels, messages, mcap_path.name)
        os.replace(tmp, mcap_path)
    except OSError as exc:
        # No room for a second copy (a full disk is how many recordings end): the messages are
        # in memory, so the truncated original itself is rewritten.
        tmp.unlink(missing_ok=True)
        try:
            text, counts = _write_recovered(mcap_path, schemas, channels, messages, mcap_path.name)
        except OSError as again:
            raise BagError(
                f"{mcap_path}: cannot write the recovered recording ({again.strerror}; first "
                f"{exc.strerror})"
            ) from None
    try:
        _write_atomically(directory / METADATA_FILE, text)
    except OSError as exc:
        raise BagError(f"{directory / METADATA_FILE}: cannot write it ({exc.strerror})") from None
    return RecoverResult(
        info=info(directory),
        messages_recovered=sum(counts.values()),
        was_complete=complete,
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
    _write_atomically(directory / METADATA_FILE, text)
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
        topics = _topic_infos(channels, schemas, counts)
        start = messages[0].log_time if messages else 0
        end = messages[-1].log_time if messages else 0
        text = metadata_yaml(mcap_name=mcap_name, start_ns=start, end_ns=end, topics=topics)
        writer.add_metadata("rosbag2", {"serialized_metadata": text, "ROS_DISTRO": ROS_DISTRO})
        writer.finish()
        out.flush()
        os.fsync(out.fileno())
    return text, counts


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
