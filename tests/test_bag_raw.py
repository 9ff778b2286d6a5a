"""`BagReader.columns` read at byte offsets (feed_twin/io/bag/raw.py) against the message
decoder's path, on flat messages of one layout, of several, and out of log-time order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.io import msg_types
from feed_twin.io.bag import BagReader, BagWriter
from feed_twin.io.bag.raw import uniform_offsets
from feed_twin.io.cdr import FlatCodec

COMMAND = FlatCodec(msg_types.AXIS_COMMAND)
HEALTH = FlatCodec(msg_types.HEALTH_STATUS)
N = 300
T0 = 1_700_000_000_000_000_000


def command(k: int, frame_id: str = "s" * 48) -> bytes:
    return COMMAND.encode_map(
        {"header.stamp.sec": k // 1000, "header.stamp.nanosec": (k % 1000) * 1_000_000,
         "header.frame_id": frame_id, "axis": "X", "position": 1e-4 * k, "velocity": -0.5 * k,
         "acceleration": 2.0, "line": k - 1}
    )  # fmt: skip


def health(k: int, message: str) -> bytes:
    return HEALTH.encode_map(
        {"header.stamp.sec": k, "header.stamp.nanosec": 0, "header.frame_id": "", "axis": "X",
         "level": k % 3, "effect": "", "parameter": "", "unit": "N", "nominal_value": 1.0,
         "estimated_value": 2.0, "relative_change": 0.5 * k, "message": message}
    )  # fmt: skip


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("raw") / "bag"
    with BagWriter(path, flush_period_s=None) as writer:
        writer.add_topic("/cnc/x/command", msg_types.AXIS_COMMAND)
        writer.add_topic("/cnc/x/health", msg_types.HEALTH_STATUS)
        writer.add_topic("/cnc/x/swapped", msg_types.HEALTH_STATUS)
        # written in batches whose log times go back (as a recorder writes packed messages)
        order = [k for start in range(0, N, 50) for k in range(start + 49, start - 1, -1)]
        for k in order:
            writer.write("/cnc/x/command", command(k), log_time_ns=T0 + k * 1_000_000)
        for k in range(10):
            writer.write("/cnc/x/health", health(k, "m" * k), log_time_ns=T0 + k)
            # one size, but the strings' lengths swap: the layout differs
            data = HEALTH.encode_map({**HEALTH.decode_map(health(k, "ab")),
                                      "unit": "N" if k % 2 else "NNN",
                                      "message": "abc" if k % 2 else "a"})  # fmt: skip
            writer.write("/cnc/x/swapped", data, log_time_ns=T0 + k)
    return path


def decoded(reader: BagReader, topic: str, fields: list[str]) -> dict[str, list]:
    """The message decoder's values, as `columns` took them before its byte-offset path."""
    out: dict[str, list] = {name: [] for name in ["log_time_s", *fields]}
    for item in reader.messages([topic]):
        out["log_time_s"].append(item.log_time_ns * 1e-9)
        for name in fields:
            value = item.msg
            for part in name.split("."):
                value = getattr(value, part)
            if hasattr(value, "sec"):
                value = value.sec + value.nanosec * 1e-9
            out[name].append(value)
    return out


def test_flat_messages_of_one_layout_read_at_offsets_equal_the_decoders(bag: Path) -> None:
    reader = BagReader(bag)
    fields = ["header.stamp", "position", "velocity", "line"]
    assert reader._flat_columns("/cnc/x/command", fields) is not None  # the byte-offset path
    cols = reader.columns("/cnc/x/command", fields)
    want = decoded(reader, "/cnc/x/command", fields)
    k = np.arange(N)
    np.testing.assert_array_equal(cols["position"], 1e-4 * k)  # in log-time order
    np.testing.assert_array_equal(cols["line"], k - 1)
    for name in ["log_time_s", *fields]:
        np.testing.assert_array_equal(cols[name], np.asarray(want[name], dtype=float))


def test_strings_or_several_layouts_go_through_the_decoder(bag: Path) -> None:
    reader = BagReader(bag)
    assert reader._flat_columns("/cnc/x/command", ["axis"]) is None  # a string
    assert reader._flat_columns("/cnc/x/health", ["relative_change"]) is None  # several sizes
    assert reader._flat_columns("/cnc/x/swapped", ["relative_change"]) is None
    for topic in ("/cnc/x/health", "/cnc/x/swapped"):
        cols = reader.columns(topic, ["relative_change", "message"])
        np.testing.assert_array_equal(cols["relative_change"], 0.5 * np.arange(10))
    assert reader.columns("/cnc/x/command", ["axis"])["axis"].tolist() == ["X"] * N


def test_uniform_offsets_checks_every_strings_length() -> None:
    same = np.frombuffer(command(1) + command(2), dtype=np.uint8).reshape(2, -1)
    assert uniform_offsets(COMMAND, same) is not None
    a, b = command(1, "s" * 48), command(2, "s" * 44)
    b = b[:-4] + b"\0" * 8  # one size, another layout
    rows = np.frombuffer(a + b, dtype=np.uint8).reshape(2, -1)
    assert uniform_offsets(COMMAND, rows) is None
