"""A bag's metadata.yaml (rosbag2 version 9): written from topic counts, read back as `BagInfo`."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Schema

from feed_twin.io.bag.layout import (
    MESSAGE_ENCODING,
    ROS_DISTRO,
    ROSBAG2_VERSION,
    BagError,
    BagInfo,
    TopicInfo,
    bag_paths,
)


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


def write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def topic_infos(channels: dict[int, Channel], schemas: dict[int, Schema], counts: dict) -> list:
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
    topics = topic_infos(summary.channels, summary.schemas, stats.channel_message_counts)
    return BagInfo(
        path=directory,
        mcap_path=mcap_path,
        start_ns=stats.message_start_time,
        end_ns=stats.message_end_time,
        message_count=stats.message_count,
        topics=tuple(topics),
    )
