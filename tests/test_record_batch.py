"""The recorder's packed copies (feed_twin/nodeset/record_batch.py) against rclpy's serialiser,
and the one-joint JointState bytes the sim publishes (feed_twin.io.cdr.JointStateLayout)."""

from __future__ import annotations

import time

import pytest
from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from feed_twin.io.cdr import ENCAPSULATION, JointStateLayout
from feed_twin.nodeset.record_batch import RecordBatch, messages_of, unpack

TOPICS = ("/cnc/x/feedback", "/cnc/x/state", "/cnc/x/joint_states")
# lengths 7, 41, 4, 1: three need padding to a multiple of 4, as Fast DDS sends a payload
MESSAGES = [
    (0, ENCAPSULATION + b"abc", 123),
    (1, ENCAPSULATION + bytes(range(37)), -5),
    (2, ENCAPSULATION, 2**62),
    (0, b"z", 7),
]


def padded(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def filled(capacity: int = 3) -> RecordBatch:
    batch = RecordBatch(TOPICS, capacity)
    for index, data, stamp in MESSAGES:
        batch.add(index, data, stamp)
    return batch


def test_batch_bytes_are_what_rclpy_serialises_and_unpack_gives_every_message_back():
    batch = filled()
    data = batch.take()
    assert data is not None
    expected = RecordBatchMsg(
        topics=list(TOPICS),
        topic=[i for i, _, _ in MESSAGES],
        publish_time_ns=[t for _, _, t in MESSAGES],
        size=[len(padded(d)) for _, d, _ in MESSAGES],
        data=b"".join(padded(d) for _, d, _ in MESSAGES),
    )
    reference = serialize_message(expected)
    assert len(data) == len(reference)
    # the same bytes but for padding, which rclpy leaves as it found it in its buffer
    differ = [i for i, (a, b) in enumerate(zip(data, reference, strict=True)) if a != b]
    assert all(data[i] == 0 for i in differ) and len(differ) <= 3 * len(TOPICS)
    back = deserialize_message(data, RecordBatchMsg)
    assert list(back.topics) == list(TOPICS)
    assert list(back.topic) == [0, 1, 2, 0]
    assert list(back.publish_time_ns) == [123, -5, 2**62, 7]
    assert list(back.size) == [8, 44, 4, 4]
    assert bytes(back.data) == bytes(expected.data)
    assert unpack(data) == [(TOPICS[i], t, padded(d)) for i, d, t in MESSAGES]
    assert batch.take() is None  # taken: empty again
    assert len(batch) == 0


def test_a_batch_is_due_after_its_capacity_of_exchanges():
    batch = RecordBatch(TOPICS, 3)
    assert [batch.end_exchange() for _ in range(3)] == [False, False, True]
    batch.add(1, ENCAPSULATION, 1)
    assert batch.take() is not None
    assert batch.end_exchange() is False  # counting starts again after take


@pytest.mark.parametrize(
    ("cut", "message"),
    [
        (lambda d: b"\x00\x00\x00\x00" + d[4:], "not little-endian CDR"),
        (lambda d: d[:30], "truncated"),
        (lambda d: d[:-3], "truncated"),
    ],
)
def test_malformed_batches_are_refused_with_the_reason(cut, message):
    data = filled().take()
    assert data is not None
    with pytest.raises(ValueError, match=message):
        unpack(cut(data))


def test_a_topic_index_outside_the_batch_is_refused():
    batch = RecordBatch(TOPICS[:1], 2)
    batch.add(1, ENCAPSULATION, 1)  # names a second topic the batch does not have
    data = batch.take()
    assert data is not None
    with pytest.raises(ValueError, match="a topic index out of range"):
        unpack(data)


def test_a_controllers_setpoint_batch_gives_its_messages_in_order_and_refuses_others():
    # the G-code node's setpoints for one controller (gcode_node --command-batch)
    command = "/cnc/y/command"
    batch = RecordBatch((command,), 50)
    sent = [ENCAPSULATION + bytes([k] * 68) for k in range(3)]
    for data in sent:
        batch.add(0, data, 7)
    packed = batch.take()
    assert packed is not None
    assert messages_of(packed, command) == sent
    with pytest.raises(ValueError, match=r"^it holds a message of /cnc/y/command, not of /cnc/x/"):
        messages_of(packed, "/cnc/x/command")
    with pytest.raises(ValueError, match="truncated"):
        messages_of(packed[:-3], command)


@pytest.mark.parametrize(
    ("topics", "capacity", "message"),
    [
        ((), 5, "topics: a batch needs at least one topic"),
        (TOPICS, 0, "capacity = 0: must be a whole number >= 1"),
        (TOPICS, 2.0, r"capacity = 2.0: must be a whole number >= 1"),
    ],
)
def test_batch_settings_are_checked(topics, capacity, message):
    with pytest.raises(ValueError, match=message):
        RecordBatch(topics, capacity)


@pytest.mark.parametrize("name", ["x", "spindle_b", "yz"])
def test_joint_state_bytes_decode_as_rclpy_reads_them(name):
    data = JointStateLayout(name).encode(12, 345_000_000, 0.125, -2.5, 1e3)
    msg = deserialize_message(data, JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (
        12,
        345_000_000,
        "",
    )
    assert list(msg.name) == [name]
    assert (msg.position[0], msg.velocity[0], msg.effort[0]) == (0.125, -2.5, 1e3)
    assert len(data) == len(serialize_message(msg))  # rclpy's padding bytes are not zeroed


@pytest.mark.ros
def test_the_recorder_writes_packed_messages_under_their_topics_and_others_from_the_topic(
    tmp_path,
):
    """X's sim and controller are the recorder's peers: their topics come packed. Y's joint
    states come from a stand-in (no sim peer on Y): recorded from the topic itself. A packed
    message of a topic the batch's node does not publish is dropped."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from feed_twin.io.bag import BagReader
    from feed_twin.io.cdr import FlatCodec
    from feed_twin.ros.batched import batch_qos
    from feed_twin.ros.dds import DATA_QOS
    from feed_twin.ros.domain import reserve_domain_id
    from feed_twin.ros.recorder_node import RecorderNode
    from feed_twin.ros.runtime import NodeOptions

    feedback = FlatCodec("feed_twin_msgs/msg/AxisFeedback").encode_map(
        {"axis": "X", "header.stamp.sec": 3, "scale_position": 0.25}
    )
    joint = JointStateLayout("y").encode(3, 0, 0.5, 0.0, 1.0)
    with reserve_domain_id() as domain:
        context = Context()
        rclpy.init(
            context=context,
            domain_id=domain.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
        )
        try:
            options = NodeOptions(
                machine="cnc", axis="x", peers=("sim", "controller", "y/standin"),
                other_axes=("y",),
            )  # fmt: skip
            recorder = RecorderNode(options, tmp_path / "bag", record_batch=4, context=context)
            producer = rclpy.create_node("producer", namespace="/cnc", context=context)
            packed = producer.create_publisher(RecordBatchMsg, "/cnc/x/record/sim", batch_qos(4))
            direct = producer.create_publisher(JointState, "/cnc/y/joint_states", DATA_QOS)
            batch = RecordBatch(("/cnc/x/feedback", "/cnc/x/command"), 4)
            batch.add(0, feedback, 1_000)
            batch.add(1, feedback, 2_000)  # not a topic of the sim: dropped
            packed.publish(batch.take())
            direct.publish(joint)
            deadline = time.monotonic() + 10.0
            while recorder.bag.message_count < 2 and time.monotonic() < deadline:
                recorder._drain()
                time.sleep(0.01)
            recorder.on_shutdown("")
            producer.destroy_node()
            recorder.destroy_node()
        finally:
            context.try_shutdown()
    reader = BagReader(tmp_path / "bag")
    counts = {t.name: t.message_count for t in reader.info.topics}
    assert counts["/cnc/x/feedback"] == 1 and counts["/cnc/y/joint_states"] == 1
    assert counts.get("/cnc/x/command", 0) == 0
    fb = reader.columns("/cnc/x/feedback", ["scale_position"])
    assert fb["scale_position"][0] == 0.25
    assert round(fb["log_time_s"][0] * 1e9) == 1_000  # logged at its publish time
    js = reader.columns("/cnc/y/joint_states", ["position[0]"])
    assert js["position[0]"][0] == 0.5
