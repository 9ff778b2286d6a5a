"""The LinuxCNC bridge's ServoSample bytes (feed_twin/linuxcnc/servo_cdr.py) against rclpy's
serialiser, and its refusals."""

from __future__ import annotations

import pytest
from feed_twin_msgs.msg import ServoSample
from rclpy.serialization import deserialize_message, serialize_message

from feed_twin.linuxcnc.servo_cdr import ARRAYS, ServoSampleLayout
from feed_twin.nodeset.auth import RunAuth

JOINTS = ("X", "Y", "Z")
# distinct values per array and joint, so that a swapped pair shows
VALUES = [float(10 * a + j) + 0.25 for a in range(len(ARRAYS)) for j in range(len(JOINTS))]


def reference(axis: str, joints: tuple[str, ...]) -> ServoSample:
    msg = ServoSample()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345_000_000
    msg.axis = axis
    msg.tick = 2**40 + 3
    msg.tick_time = 9876.5
    msg.line = 42
    msg.joints = list(joints)
    n = len(joints)
    for a, name in enumerate(ARRAYS):
        setattr(msg, name, [float(10 * a + j) + 0.25 for j in range(n)])
    return msg


@pytest.mark.parametrize("axis", ["X", "Yaw", ""])
def test_the_bytes_are_rclpys_and_read_back_field_by_field(axis: str) -> None:
    data = ServoSampleLayout(axis, JOINTS).encode(12, 345_000_000, 2**40 + 3, 9876.5, 42, VALUES)
    expected = reference(axis, JOINTS)
    wire = serialize_message(expected)
    assert len(data) == len(wire)
    # the same bytes but for padding, which rclpy leaves as it found it in its buffer
    differ = [i for i, (a, b) in enumerate(zip(data, wire, strict=True)) if a != b]
    assert all(data[i] == 0 for i in differ)
    back = deserialize_message(data, ServoSample)
    assert back == expected


def test_one_joint_and_a_signature_in_frame_id() -> None:
    layout = ServoSampleLayout("X", ("X",))
    data = layout.encode(1, 2, 3, 4.0, 0, [0.5 * k for k in range(len(ARRAYS))])
    auth = RunAuth(b"k" * 32)
    signed = auth.sign("/cnc/x/linuxcnc/servo", data)
    back = deserialize_message(signed, ServoSample)
    assert back.following_error.tolist() == [2.0] and back.header.frame_id != ""
    assert auth.verify("/cnc/x/linuxcnc/servo", signed) is not None


def test_refusals_name_what_is_wrong() -> None:
    with pytest.raises(ValueError, match="joints: a servo sample needs at least one joint"):
        ServoSampleLayout("X", ())
    with pytest.raises(ValueError, match=r"values: 17 numbers, expected 6 arrays x 3 joints"):
        ServoSampleLayout("X", JOINTS).encode(0, 0, 0, 0.0, 0, VALUES[:-1])


def test_a_bags_samples_read_back_at_byte_offsets_equal_the_decoders(tmp_path) -> None:
    """read_servo_trace's byte-offset path (the bridge's signed samples of one layout) against
    the message decoder, and a ServoSample of another shape read through the decoder."""
    import numpy as np

    from feed_twin.io.bag import BagReader, BagWriter
    from feed_twin.linuxcnc.dashboard import read_servo_trace

    auth = RunAuth(b"k" * 32)
    layout = ServoSampleLayout("X", JOINTS)
    topic, odd = "/cnc/x/linuxcnc/servo", "/cnc/x/other/servo"
    with BagWriter(tmp_path / "bag", flush_period_s=None) as bag:
        bag.add_topic(topic, "feed_twin_msgs/msg/ServoSample")
        bag.add_topic(odd, "feed_twin_msgs/msg/ServoSample")
        for k in range(200):
            values = [v * (k + 1) for v in VALUES]
            data = layout.encode(k // 1000, (k % 1000) * 1_000_000, k, 5.0 + k * 1e-3, 1, values)
            bag.write(topic, auth.sign(topic, data), log_time_ns=10**18 + k)
            msg = reference("X", JOINTS)
            msg.tick, msg.servo_output = k, [0.5 * k, 0.0]  # two values for three joints
            bag.write(odd, bytes(serialize_message(msg)), log_time_ns=10**18 + k)
    trace = read_servo_trace(tmp_path / "bag", topic)
    reader = BagReader(tmp_path / "bag")
    names = [f"following_error[{j}]" for j in range(3)]
    want = reader.columns(topic, ["header.stamp", "tick_time", *names])
    assert reader._flat_columns(topic, names) is None  # not flat: the decoder's values
    np.testing.assert_array_equal(trace.t_s, want["header.stamp"])
    np.testing.assert_array_equal(trace.tick_time_s, want["tick_time"])
    for j, name in enumerate(names):
        np.testing.assert_array_equal(trace.following_error_m[:, j], want[name])
    assert trace.following_error_m[3].tolist() == [4 * v for v in VALUES[12:15]]
    other = read_servo_trace(tmp_path / "bag", odd, joints=("X", "Y"))
    assert other.servo_output_m_s[:, 0].tolist() == [0.5 * k for k in range(200)]


def test_a_message_of_another_shape_is_refused_by_name() -> None:
    msg = reference("X", JOINTS)
    msg.servo_output = [1.0]
    with pytest.raises(ValueError, match=r"not a ServoSample with one value per joint in each "
                       r"array \(\d+ bytes, \d+ expected for joints X, Y, Z\)"):  # fmt: skip
        ServoSampleLayout.from_message(bytes(serialize_message(msg)))
    with pytest.raises(ValueError, match=r"^not a ServoSample \(unpack_from requires"):
        ServoSampleLayout.from_message(b"\x00\x01\x00\x00" + b"\x00" * 10)
    layout = ServoSampleLayout("X", JOINTS)
    import numpy as np

    with pytest.raises(ValueError, match=r"rows of 3 bytes: this layout's are \d+"):
        layout.read(np.zeros((2, 3), dtype=np.uint8))
    a = layout.encode(0, 0, 0, 0.0, 0, VALUES)
    b = ServoSampleLayout("Y", ("X", "YY", "")).encode(0, 0, 0, 0.0, 0, VALUES)
    assert len(a) == len(b)
    rows = np.frombuffer(a + b, dtype=np.uint8).reshape(2, -1)
    with pytest.raises(ValueError, match=r"rows of several layouts: joints\[1\] differs"):
        layout.read(rows)
