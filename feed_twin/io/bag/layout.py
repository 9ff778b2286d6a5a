"""The rosbag2 layout shared by writer, reader and recovery: constants, errors, QoS, paths."""

from __future__ import annotations

import datetime
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml

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
            f"start:     {_utc(self.start_ns)}",
            f"end:       {_utc(self.end_ns)}",
            f"messages:  {self.message_count}",
            f"topics:    {len(self.topics)}",
        ]
        for t in self.topics:
            lines.append(
                f"  {t.name:<{width}}  {t.type_name:<{type_width}}  {t.message_count:>9} msgs"
            )
        return "\n".join(lines)


Y2K_NS = 946_684_800 * 1_000_000_000  # earlier receive times are a simulated clock's


def _utc(ns: int) -> str:
    """A receive time (ns since the epoch) as a reader wants it: 2026-11-28 10:03:25.123456 UTC
    (the epoch seconds follow in brackets, for scripts); a bag written on a simulated clock
    (an in-process run: times from 0) gives its seconds."""
    if ns < Y2K_NS:
        return f"{ns * 1e-9:.6f} s (simulated clock, not a date)"
    when = datetime.datetime.fromtimestamp(ns // 1_000_000_000, tz=datetime.UTC)
    micros = (ns % 1_000_000_000) // 1000
    return f"{when:%Y-%m-%d %H:%M:%S}.{micros:06d} UTC ({ns * 1e-9:.3f} s since 1970)"


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
