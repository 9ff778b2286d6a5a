"""Typed reads of a bag through rosbags, for the tests that check it as an independent reader.

rosbags builds its message classes at run time from the stored definitions, so
`deserialize_cdr` is typed to return `object`, and a connection's `ext` is the rosbag1 or
rosbag2 extension; these say what a rosbag2 bag holds.
"""

from __future__ import annotations

from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2
from rosbags.typesys.store import Typestore


def decode(store: Typestore, raw: bytes, msgtype: str) -> Any:
    """The message of `raw` (CDR) as rosbags' dataclass of `msgtype`, its fields read by name."""
    return store.deserialize_cdr(raw, msgtype)


def offered_qos(connection: Connection) -> list[Any]:
    """The QoS profiles a rosbag2 connection records as offered by its publishers."""
    ext = connection.ext
    assert isinstance(ext, ConnectionExtRosbag2), f"{connection.topic}: not a rosbag2 topic"
    return ext.offered_qos_profiles
