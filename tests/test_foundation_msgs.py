"""feed_twin_msgs: every message type round-trips over DDS field by field; the definitions
carry a unit for every physical field and agree with the core's constants."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from feed_twin_msgs.msg import AxisFeedback, DriveCommand, HealthStatus

from feed_twin.core import signals
from feed_twin.ros import msgcheck
from feed_twin.ros.domain import private_graph_env, reserve_domain_id

MSG_DIR = Path(__file__).resolve().parents[1] / "msgs" / "msg"


def _leaf_count(message) -> int:
    """Leaf fields of a message: nested messages opened up, a sequence counted as one."""
    count = 0
    for name in message.get_fields_and_field_types():
        value = getattr(message, name)
        if hasattr(value, "get_fields_and_field_types"):
            count += _leaf_count(value)
        else:
            count += 1
    return count


@pytest.mark.ros
def test_every_message_type_round_trips_over_dds_with_every_field(ros_domain_id):
    messages = [
        msgcheck.filled_message(t, seed=1000 * i) for i, t in enumerate(msgcheck.MESSAGE_TYPES)
    ]
    results = msgcheck.round_trip(messages, domain_id=ros_domain_id, timeout_s=20.0)

    assert [r.type_name for r in results] == [
        "feed_twin_msgs/msg/AxisCommand",
        "feed_twin_msgs/msg/DriveCommand",
        "feed_twin_msgs/msg/AxisFeedback",
        "feed_twin_msgs/msg/AxisState",
        "feed_twin_msgs/msg/TwinResidual",
        "feed_twin_msgs/msg/HealthStatus",
        "feed_twin_msgs/msg/ServoSample",
        "sensor_msgs/msg/JointState",
        "rosgraph_msgs/msg/Clock",
    ]
    for result in results:
        assert result.received is not None, f"{result.type_name}: nothing received"
        assert result.differences == [], result.type_name
        # The received copy is a new object from the wire, not the sent one.
        assert result.received is not result.sent
        assert result.latency_s > 0.0


@pytest.mark.ros
@pytest.mark.slow  # starts a second Python with rclpy: 1-4 s depending on the machine's load
def test_every_message_type_arrives_intact_from_a_node_in_another_process(ros_domain_id):
    results = msgcheck.round_trip_between_processes(domain_id=ros_domain_id, timeout_s=30.0)
    assert [r.type_name for r in results] == [msgcheck.type_name(t) for t in msgcheck.MESSAGE_TYPES]
    for result in results:
        assert result.received is not None, f"{result.type_name}: nothing received"
        assert result.differences == [], result.type_name


@pytest.mark.parametrize("msg_type", msgcheck.MESSAGE_TYPES, ids=lambda t: t.__name__)
def test_filled_message_differs_from_default_in_every_leaf(msg_type):
    filled = msgcheck.filled_message(msg_type)
    # Every leaf differs from the default, so a field lost in transit cannot go unnoticed.
    assert len(msgcheck.field_differences(filled, msg_type())) == _leaf_count(filled)


def test_field_differences_names_the_changed_field():
    sent = msgcheck.filled_message(DriveCommand)
    received = msgcheck.filled_message(DriveCommand)
    received.i_q = -received.i_q
    received.header.stamp.nanosec += 1
    assert msgcheck.field_differences(sent, received) == [
        f"header.stamp.nanosec: {sent.header.stamp.nanosec} != {sent.header.stamp.nanosec + 1}",
        f"i_q: {sent.i_q} != {-sent.i_q}",
    ]


def test_round_trip_rejects_a_nonpositive_timeout(ros_domain_id):
    with pytest.raises(ValueError, match=r"timeout_s = 0\.0: must be > 0"):
        msgcheck.round_trip([], domain_id=ros_domain_id, timeout_s=0.0)


def test_fault_codes_match_the_core_signal_layout():
    assert AxisFeedback.FAULT_NONE == signals.FAULT_NONE
    assert AxisFeedback.FAULT_FOLLOWING_ERROR == signals.FAULT_FOLLOWING_ERROR
    assert AxisFeedback.FAULT_OVERCURRENT == signals.FAULT_OVERCURRENT
    assert AxisFeedback.FAULT_DISABLED == signals.FAULT_DISABLED
    constants = {n for n in dir(AxisFeedback) if n.startswith("FAULT_") and n.isupper()}
    assert len(constants) == len(signals.FAULT_REASONS)


def test_status_word_bits_are_the_cia402_bits():
    bits = {
        name: getattr(AxisFeedback, name)
        for name in dir(AxisFeedback)
        if name.startswith("STATUS_") and name.isupper()
    }
    expected_bit = {
        "STATUS_READY_TO_SWITCH_ON": 0,
        "STATUS_SWITCHED_ON": 1,
        "STATUS_OPERATION_ENABLED": 2,
        "STATUS_FAULT": 3,
        "STATUS_VOLTAGE_ENABLED": 4,
        "STATUS_QUICK_STOP": 5,
        "STATUS_SWITCH_ON_DISABLED": 6,
        "STATUS_WARNING": 7,
        "STATUS_REMOTE": 9,
        "STATUS_TARGET_REACHED": 10,
        "STATUS_INTERNAL_LIMIT_ACTIVE": 11,
        "STATUS_DRIVE_FOLLOWS_COMMAND": 12,
        "STATUS_FOLLOWING_ERROR": 13,
    }
    assert bits == {name: 1 << bit for name, bit in expected_bit.items()}


def test_modes_are_the_cia402_cyclic_synchronous_modes():
    assert DriveCommand.MODE_CYCLIC_SYNC_POSITION == 8
    assert DriveCommand.MODE_CYCLIC_SYNC_VELOCITY == 9
    assert DriveCommand.MODE_CYCLIC_SYNC_TORQUE == 10
    assert DriveCommand.MODE_VOLTAGE < 0  # manufacturer-specific modes are negative in CiA 402


def test_health_levels_match_diagnostic_status():
    from diagnostic_msgs.msg import DiagnosticStatus

    levels = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
    levels += (DiagnosticStatus.STALE,)
    assert tuple(int.from_bytes(level, "little") for level in levels) == (
        HealthStatus.OK,
        HealthStatus.WARN,
        HealthStatus.ERROR,
        HealthStatus.STALE,
    )


_FIELD = re.compile(r"^(?P<type>[\w/\[\]<>=,]+)\s+(?P<name>[a-z][a-z0-9_]*)\s*(?:#\s*(?P<c>.*))?$")
# Fields whose meaning is not a physical quantity: names, flags, enumerations, stamps.
_UNITLESS_TYPES = {"string", "bool", "std_msgs/Header"}
_UNITLESS_NAMES = {"mode", "status_word", "fault_code", "level"}


@pytest.mark.parametrize("path", sorted(MSG_DIR.glob("*.msg")), ids=lambda p: p.name)
def test_every_field_has_a_comment_and_every_quantity_a_unit(path):
    fields = 0
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if "=" in stripped.split("#")[0]:
            continue  # a constant
        match = _FIELD.match(stripped)
        assert match, f"{path.name}:{number}: cannot read {stripped!r}"
        fields += 1
        comment = match["c"] or ""
        assert comment, f"{path.name}:{number}: field {match['name']} has no comment"
        if match["type"] not in _UNITLESS_TYPES and match["name"] not in _UNITLESS_NAMES:
            assert re.search(r"\[[^\]]+\]", comment), (
                f"{path.name}:{number}: field {match['name']} has no [unit] in its comment"
            )
    assert fields >= 5  # the smallest, RecordBatch, has five


def test_every_message_has_a_header_and_an_axis_name():
    for msg_type in msgcheck.FEED_TWIN_MESSAGE_TYPES:
        fields = msg_type.get_fields_and_field_types()
        assert fields["header"] == "std_msgs/Header", msg_type.__name__
        assert fields["axis"] == "string", msg_type.__name__


def test_filled_message_names_an_unsupported_field_type():
    from std_msgs.msg import Byte

    with pytest.raises(
        ValueError, match=r"^field type 'octet' is not supported by filled_message$"
    ):
        msgcheck.filled_message(Byte)


def test_field_differences_names_elements_of_message_sequences():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    sent = DiagnosticArray(status=[DiagnosticStatus(name="a"), DiagnosticStatus(name="b")])
    shorter = DiagnosticArray(status=[DiagnosticStatus(name="a")])
    assert msgcheck.field_differences(sent, shorter) == ["status: 2 elements != 1"]
    changed = DiagnosticArray(status=[DiagnosticStatus(name="a"), DiagnosticStatus(name="c")])
    assert msgcheck.field_differences(sent, changed) == ["status[1].name: 'b' != 'c'"]


@pytest.mark.ros
def test_a_talker_without_listener_gives_up_and_says_so():
    with reserve_domain_id() as domain:
        result = subprocess.run(
            [sys.executable, "-m", "feed_twin.ros.msgcheck", "--talker", str(domain.domain_id)]
            + ["--timeout", "0.5"],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, **private_graph_env(domain.domain_id)},
        )
    assert result.returncode == 1
    assert result.stderr.splitlines()[-1] == (
        f"msgcheck talker: no listener matched within 0.5 s (domain {domain.domain_id})"
    )
