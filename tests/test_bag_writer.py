"""Bags written by feed_twin.io.bag, read back by the independent `rosbags` reader."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags_support import offered_qos
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from feed_twin.io.bag import BagError, BagReader, BagWriter, QosProfile, info
from feed_twin.io.bag.schema import (
    DEPENDENCY_SEPARATOR,
    MessageTypeError,
    message_definition,
    nested_types,
)

N = 250
DT_NS = 1_000_000  # 1 kHz exchange period


def joint_state(k: int) -> bytes:
    msg = JointState()
    msg.header.stamp.sec = (k * DT_NS) // 1_000_000_000
    msg.header.stamp.nanosec = (k * DT_NS) % 1_000_000_000
    msg.name = ["x"]
    msg.position = [1e-4 * k]
    msg.velocity = [0.05]
    # A non-empty effort: rclpy's serialize_message may pad messages with an empty trailing
    # sequence (ROS notes); the recorder itself stores DDS wire bytes and is not affected.
    msg.effort = [-2.5 * k]
    return bytes(serialize_message(msg))


def write_sample_bag(path: Path) -> None:
    with BagWriter(path, flush_period_s=None) as bag:
        bag.add_topic("/m/x/joint_states", "sensor_msgs/msg/JointState")
        bag.add_topic(
            "/m/x/scalar", "std_msgs/msg/Float64", qos=(QosProfile(depth=1, lifespan_s=0.25),)
        )
        for k in range(N):
            t = 1_700_000_000_000_000_000 + k * DT_NS
            bag.write("/m/x/joint_states", joint_state(k), log_time_ns=t, publish_time_ns=t - 7)
            if k % 2 == 0:
                bag.write(
                    "/m/x/scalar", bytes(serialize_message(Float64(data=0.5 * k))), log_time_ns=t
                )


@pytest.fixture(scope="module")
def sample_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "sample"
    write_sample_bag(path)
    return path


def test_rosbags_reads_counts_types_and_values(sample_bag: Path) -> None:
    store = get_typestore(Stores.EMPTY)
    got: dict[str, list] = {"/m/x/joint_states": [], "/m/x/scalar": []}
    with Reader(sample_bag) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert {t: c.msgtype for t, c in conns.items()} == {
            "/m/x/joint_states": "sensor_msgs/msg/JointState",
            "/m/x/scalar": "std_msgs/msg/Float64",
        }
        assert conns["/m/x/joint_states"].msgcount == N
        assert conns["/m/x/scalar"].msgcount == (N + 1) // 2
        for conn in reader.connections:
            assert conn.msgdef.format.name == "MSG"
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, store.deserialize_cdr(raw, conn.msgtype)))
        assert reader.duration == (N - 1) * DT_NS + 1
    js = got["/m/x/joint_states"]
    assert len(js) == N
    for k, (t, msg) in enumerate(js):
        assert t == 1_700_000_000_000_000_000 + k * DT_NS
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == k * DT_NS
        assert list(msg.name) == ["x"]
        assert msg.position[0] == pytest.approx(1e-4 * k, abs=0.0)
        assert msg.effort[0] == -2.5 * k
    scalars = [msg.data for _, msg in got["/m/x/scalar"]]
    assert scalars == [0.5 * k for k in range(0, N, 2)]


def test_qos_and_type_hash_are_stored_per_topic(sample_bag: Path) -> None:
    with Reader(sample_bag) as reader:
        conns = {c.topic: c for c in reader.connections}
    scalar = conns["/m/x/scalar"]
    (qos,) = offered_qos(scalar)
    assert qos.depth == 1
    assert qos.reliability.name == "RELIABLE"
    assert qos.lifespan.sec == 0 and qos.lifespan.nsec == 250_000_000
    hashes = json.loads(
        (Path(sys.prefix) / "share/std_msgs/msg/Float64.json").read_text(encoding="utf-8")
    )["type_hashes"]
    expected = next(h["hash_string"] for h in hashes if h["type_name"] == "std_msgs/msg/Float64")
    assert scalar.digest == expected
    assert expected.startswith("RIHS01_")


def test_metadata_yaml_is_rosbag2_version_9(sample_bag: Path) -> None:
    meta = yaml.safe_load((sample_bag / "metadata.yaml").read_text(encoding="utf-8"))
    bag = meta["rosbag2_bagfile_information"]
    assert bag["version"] == 9
    assert bag["storage_identifier"] == "mcap"
    assert bag["relative_file_paths"] == ["sample_0.mcap"]
    assert bag["message_count"] == N + (N + 1) // 2
    assert bag["duration"]["nanoseconds"] == (N - 1) * DT_NS
    topics = {t["topic_metadata"]["name"]: t for t in bag["topics_with_message_count"]}
    assert topics["/m/x/joint_states"]["message_count"] == N
    qos = yaml.safe_load(topics["/m/x/joint_states"]["topic_metadata"]["offered_qos_profiles"])
    assert qos[0]["history"] == "keep_last" and qos[0]["depth"] == 10


def test_schema_has_dependency_blocks_in_depth_first_order() -> None:
    definition = message_definition("sensor_msgs/msg/JointState")
    assert definition.dependencies == ("std_msgs/msg/Header", "builtin_interfaces/msg/Time")
    blocks = definition.schema_text.split(DEPENDENCY_SEPARATOR + "\n")
    assert len(blocks) == 3
    assert blocks[1].startswith("MSG: std_msgs/Header\n")
    assert blocks[2].startswith("MSG: builtin_interfaces/Time\n")
    assert "float64[] position" in blocks[0]


def test_nested_types_parses_arrays_bounds_constants_and_comments() -> None:
    text = (
        "# a comment with pkg/Fake inside\n"
        "int32 MODE_X=3\n"
        "string<=8 label\n"
        "Point[<=4] corners  # same package\n"
        "geometry_msgs/Vector3[] v\n"
        "builtin_interfaces/msg/Time stamp\n"
        "uint8[16] raw\n"
    )
    assert nested_types(text, "pkg") == (
        "pkg/msg/Point",
        "geometry_msgs/msg/Vector3",
        "builtin_interfaces/msg/Time",
    )


def test_bag_reader_columns_match_written_values(sample_bag: Path) -> None:
    reader = BagReader(sample_bag)
    cols = reader.columns("/m/x/joint_states", ["position[0]", "header.stamp", "name[0]"])
    k = np.arange(N)
    np.testing.assert_allclose(cols["position[0]"], 1e-4 * k, rtol=0, atol=1e-15)
    np.testing.assert_allclose(cols["header.stamp"], k * DT_NS * 1e-9, rtol=0, atol=1e-12)
    assert set(cols["name[0]"]) == {"x"}
    assert cols["log_time_s"][1] - cols["log_time_s"][0] == pytest.approx(1e-3, abs=1e-6)
    first = next(reader.messages(["/m/x/scalar"]))
    assert first.type_name == "std_msgs/msg/Float64" and first.msg.data == 0.0


def test_info_summarises_topics(sample_bag: Path) -> None:
    summary = info(sample_bag)
    assert summary.message_count == N + (N + 1) // 2
    assert summary.duration_s == pytest.approx((N - 1) * 1e-3, abs=1e-12)
    text = summary.format()
    assert "/m/x/joint_states" in text and "sensor_msgs/msg/JointState" in text
    assert f"{N} msgs" in text


def test_cli_bag_info(sample_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from feed_twin.cli import main

    assert main(["bag", "info", str(sample_bag)]) == 0
    out = capsys.readouterr().out
    assert "std_msgs/msg/Float64" in out and "duration:  0.249000 s" in out
    assert main(["bag", "info", str(sample_bag / "nope")]) == 1
    assert "no such bag directory" in capsys.readouterr().err


def test_writer_error_messages(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"flush_period_s = 0.0: must be > 0 or None"):
        BagWriter(tmp_path / "a", flush_period_s=0.0)
    bag = BagWriter(tmp_path / "b", flush_period_s=None)
    with pytest.raises(BagError, match=r"topic 'x': must be an absolute name"):
        bag.add_topic("x", "std_msgs/msg/Float64")
    with pytest.raises(MessageTypeError, match=r"expected the form package/msg/Type"):
        bag.add_topic("/x", "std_msgs/Float64")
    with pytest.raises(MessageTypeError, match=r"'no_such_pkg' is not installed"):
        bag.add_topic("/x", "no_such_pkg/msg/Thing")
    with pytest.raises(MessageTypeError, match=r"std_msgs/msg/NoSuchType.*does not exist"):
        bag.add_topic("/x", "std_msgs/msg/NoSuchType")
    with pytest.raises(BagError, match=r"topic '/x' is not registered; call add_topic first"):
        bag.write("/x", b"\x00\x01\x00\x00", log_time_ns=0)
    bag.add_topic("/x", "std_msgs/msg/Float64")
    bag.add_topic("/x", "std_msgs/msg/Float64")
    with pytest.raises(BagError, match=r"already recorded as std_msgs/msg/Float64, not std_msgs"):
        bag.add_topic("/x", "std_msgs/msg/Int32")
    bag.close()
    with pytest.raises(BagError, match=r"the bag is closed"):
        bag.write("/x", b"", log_time_ns=0)
    with pytest.raises(BagError, match=r"exists and is not empty"):
        BagWriter(tmp_path / "b")


def test_qos_profile_validation() -> None:
    with pytest.raises(ValueError, match=r"depth = -1: must be a whole number >= 0"):
        QosProfile(depth=-1)
    with pytest.raises(ValueError, match=r"deadline_s = -1.0: must be >= 0"):
        QosProfile(deadline_s=-1.0)
    d = QosProfile(deadline_s=1.5).to_dict()
    assert d["deadline"] == {"sec": 1, "nsec": 500_000_000}
    assert QosProfile().to_dict()["lifespan"]["sec"] == 9223372036
    assert math.isinf(QosProfile().lifespan_s)


def test_reader_error_messages(sample_bag: Path, tmp_path: Path) -> None:
    reader = BagReader(sample_bag)
    with pytest.raises(BagError, match=r"no topic '/nope' in the bag \(topics: /m/x/joint"):
        reader.columns("/nope", ["data"])
    with pytest.raises(BagError, match=r"message has no field 'datum' \(at 'datum'\)"):
        reader.columns("/m/x/scalar", ["datum"])
    with pytest.raises(BagError, match=r"field 'position\[3\]' has 1 entries, no \[3\]"):
        reader.columns("/m/x/joint_states", ["position[3]"])
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match=r"expected one .mcap file in the bag directory"):
        BagReader(empty)
