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
