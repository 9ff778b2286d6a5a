"""The node set's pure parts: CDR codec, configuration, NC stream rules, controller split."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from controller_support import position_loop, velocity_loop
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, AxisState, DriveCommand
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags_support import decode

from feed_twin.control.config import load_controller_config
from feed_twin.core.config import ConfigError
from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.io.bag.schema import message_definition
from feed_twin.io.cdr import FlatCodec, NotFlatError
from feed_twin.nodeset.config import NodeLoopGains, NodeSetConfig, load_node_set_config
from feed_twin.nodeset.controller_core import (
    ControllerCore,
    controller_node_config,
    feed_forward_delays,
)
from feed_twin.nodeset.nc_buffer import NcBuffer
from feed_twin.nodeset.reference_delay import DelayedReference
from feed_twin.nodeset.summary import summarise
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.nodeset.wire import (
    MODE_CSP,
    MODE_CST,
    MODE_CSV,
    DriveSetpoint,
    NcSample,
    drive_reference,
)
from feed_twin.ros.gcode_node import ProgramStream

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
NC = ROOT / "config" / "axis_default.yaml"
HOT_TYPES = {
    "feed_twin_msgs/msg/AxisCommand": AxisCommand,
    "feed_twin_msgs/msg/DriveCommand": DriveCommand,
    "feed_twin_msgs/msg/AxisFeedback": AxisFeedback,
    "feed_twin_msgs/msg/AxisState": AxisState,
}


def _values(codec: FlatCodec, seed: int) -> list:
    rng = np.random.default_rng(seed)
    out: list = []
    for name, kind in codec.fields:
        if kind == "string":
            out.append(["", "X", "axis_z2"][seed % 3] if name == "axis" else "f" * (seed % 5))
        elif kind.startswith("float"):
            out.append(float(rng.normal() * 10.0 ** rng.integers(-9, 4)))
        elif kind == "bool":
            out.append(bool(seed % 2))
        elif kind.startswith("uint"):
            out.append(int(rng.integers(0, 2 ** int(kind[4:]))))
        else:
            bits = int(kind[3:]) - 1
            out.append(int(rng.integers(-(2**bits), 2**bits)))
    return out


def _to_message(msg_type: type, codec: FlatCodec, values: list):
    msg = msg_type()
    for (name, _), value in zip(codec.fields, values, strict=True):
        obj = msg
        *path, leaf = name.split(".")
        for part in path:
            obj = getattr(obj, part)
        setattr(obj, leaf, value)
    return msg


@pytest.mark.parametrize("type_name", sorted(HOT_TYPES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cdr_codec_matches_rclpy_and_rosbags(type_name: str, seed: int) -> None:
    codec = FlatCodec(type_name)
    values = _values(codec, seed)
    ours = codec.encode(values)
    theirs = bytes(serialize_message(_to_message(HOT_TYPES[type_name], codec, values)))
    # rclpy leaves its alignment padding uninitialised; every value byte must agree.
    assert len(ours) == len(theirs)
    assert codec.decode(theirs) == tuple(values)
    assert codec.decode(ours) == tuple(values)
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(message_definition(type_name).schema_text, type_name))
    decoded = decode(store, ours, type_name)
    assert decoded.axis == values[codec.index("axis")]
    assert decoded.header.stamp.sec == values[codec.index("header.stamp.sec")]


def test_cdr_codec_errors() -> None:
    with pytest.raises(NotFlatError, match=r"JointState: field 'name' of type 'string\[\]'"):
        FlatCodec("sensor_msgs/msg/JointState")
    codec = FlatCodec("feed_twin_msgs/msg/AxisCommand")
    with pytest.raises(KeyError, match=r"AxisCommand has no field\(s\) speed"):
        codec.encode_map({"speed": 1.0})
    with pytest.raises(ValueError, match=r"not little-endian CDR"):
        codec.decode(b"\x00\x00\x00\x00" + bytes(60))


def test_node_set_config_defaults_and_errors(tmp_path: Path) -> None:
    ros = NodeSetConfig()
    assert (ros.machine, ros.axis, ros.boundary, ros.exchange_ns) == ("cnc", "x", "torque", 10**6)
    with pytest.raises(ValueError, match=r"exchange_period_s = -0.001: must be > 0"):
        NodeSetConfig(exchange_period_s=-1e-3)
    with pytest.raises(ValueError, match=r"clock_divider = 60: must lie in \[1, lookahead - 1\]"):
        NodeSetConfig(clock_divider=60)
    with pytest.raises(ValueError, match=r"velocity_Kp = 0.0: must be > 0"):
        NodeLoopGains(velocity_Kp=0.0)
    path = tmp_path / "axis.yaml"
    path.write_text(yaml.safe_dump({"ros": {"boundary": "current"}}))
    with pytest.raises(ConfigError, match=r"axis.yaml: ros.boundary = 'current': must be one of"):
        load_node_set_config(path)
    path.write_text(yaml.safe_dump({"ros": {"machine": "Mill 1"}}))
    with pytest.raises(ConfigError, match=r"ros.machine = 'Mill 1': must be a lower-case ROS"):
        load_node_set_config(path)
    path.write_text(yaml.safe_dump({"plant": {}}))
    assert load_node_set_config(path) == NodeSetConfig()


def test_topics_are_namespaced() -> None:
    topics = AxisTopics(machine="mill2", axis="z")
    assert topics.command == "/mill2/z/command"
    assert topics.types()[topics.state] == "feed_twin_msgs/msg/AxisState"
    assert topics.types()["/clock"] == "rosgraph_msgs/msg/Clock"
    for name in topics.types():
        message_definition(topics.types()[name])  # every type is installed
    with pytest.raises(ValueError, match=r"axis = 'X': must be a lower-case ROS name"):
        AxisTopics(machine="m", axis="X")


def test_controller_node_config_runs_loops_at_the_exchange() -> None:
    config = load_controller_config(yaml.safe_load(AXIS.read_text())["controller"], str(AXIS))
    derived, notes = controller_node_config(config, 1e-3)
    assert derived.current is None and derived.base_period_s == 1e-3
    velocity, position = velocity_loop(derived), position_loop(derived)
    assert velocity.period_s == 1e-3 and position.period_s == 1e-3
    # The symmetric optimum for T_sigma = current lag + hold + estimator + one exchange of
    # transport: Kp = J (2 pi/lead) / (K_t a T_sigma) with a = 2.
    T_sigma = 3 * 62.5e-6 + 0.5e-3 + (0.5e-3 + 0.5e-3) + 1e-3
    drive = config.drive
    expected = drive.J_total_kg_m2 * (2 * math.pi / drive.lead_m) / (drive.K_t * 2 * T_sigma)
    assert velocity.Kp == pytest.approx(expected, rel=1e-9)
    assert velocity.Ti_s == pytest.approx(4 * T_sigma, rel=1e-9)
    assert any("re-tuned" in n for n in notes)
    fixed, _ = controller_node_config(
        config, 1e-3, NodeLoopGains(velocity_Kp=300.0, velocity_Ti_s=0.02, Kv_1_s=30.0)
    )
    fixed_vel, fixed_pos = velocity_loop(fixed), position_loop(fixed)
    assert (fixed_vel.Kp, fixed_vel.Ti_s, fixed_pos.Kv_1_s) == (300.0, 0.02, 30.0)
    slow = dataclasses.replace(
        config, velocity=dataclasses.replace(velocity_loop(config), period_s=1.5e-3)
    )
    with pytest.raises(ValueError, match=r"velocity.period_s = 0.0015: must be a multiple of the"):
        controller_node_config(slow, 1e-3)


def test_nc_buffer_picks_the_setpoint_for_each_exchange() -> None:
    buffer = NcBuffer()

    def sample(t_ms: int, x: float) -> NcSample:
        return NcSample(
            t_ns=t_ms * 10**6, position_m=x, velocity_m_s=1.0, acceleration_m_s2=0.0, line=3
        )

    def known(t_ns: int) -> NcSample:
        setpoint = buffer.for_time(t_ns)
        assert setpoint is not None, f"the buffer knows no setpoint for t = {t_ns} ns"
        return setpoint

    assert buffer.for_time(0) is None
    buffer.add(sample(0, 0.0))
    buffer.add(sample(2, 0.002))
    assert known(0).position_m == 0.0
    # t = 1 ms: the setpoint of 0 ms still holds (2 ms is known, so nothing else can come).
    assert known(10**6).position_m == 0.0
    assert known(2 * 10**6).position_m == 0.002
    assert buffer.for_time(3 * 10**6) is None  # not known yet
    buffer.finish()
    held = known(3 * 10**6)
    assert (held.position_m, held.velocity_m_s, held.line) == (0.002, 0.0, -1)


def test_drive_reference_per_mode() -> None:
    ref = np.zeros(6)
    drive_reference(DriveSetpoint(t_ns=0, mode=MODE_CST, enable=True, i_q_A=2.5), 1.9, ref)
    assert ref[4] == 2.5 and ref.sum() == 2.5
    drive_reference(
        DriveSetpoint(t_ns=0, mode=MODE_CSV, enable=True, velocity_m_s=0.1, torque_Nm=3.8),
        1.9,
        ref,
    )
    assert ref[3] == 0.1 and ref[5] == pytest.approx(2.0)
    drive_reference(
        DriveSetpoint(t_ns=0, mode=MODE_CSP, enable=True, position_m=0.3, velocity_m_s=0.1),
        1.9,
        ref,
    )
    assert (ref[0], ref[1]) == (0.3, 0.1)
    # MODE_VOLTAGE bypasses the cascade (the modulator takes u_d/u_q): no reference at all.
    drive_reference(DriveSetpoint(t_ns=0, mode=-1, enable=True, u_q_V=5.0), 1.9, ref)
    assert not ref.any()
    with pytest.raises(ValueError, match=r"DriveCommand mode = 7: not one of -1, 8, 9, 10"):
        drive_reference(DriveSetpoint(t_ns=0, mode=7, enable=True), 1.9, ref)
    config = load_controller_config(yaml.safe_load(AXIS.read_text())["controller"], str(AXIS))
    with pytest.raises(ValueError, match=r"boundary = 'current': must be one of"):
        # the bad value under test
        ControllerCore(config, boundary="current", exchange_period_s=1e-3)  # pyright: ignore[reportArgumentType]


PROGRAM = """G21 G90 G54 G64
G1 X10 F3000
M0
G1 X0
M30
"""


def test_program_stream_pauses_holds_and_resumes() -> None:
    nc = load_nc_config(NC)
    trajectory = plan_program(PROGRAM, nc)
    stream = ProgramStream(trajectory, "X", period_ns=10**6, t0_ns=0, optional_stop=False)
    samples = []
    while stream.paused is None:
        samples.append(stream.next_sample())
    # Machine coordinates: the program starts at X = 0.4 m and G54 X10 is 0.41 m.
    assert samples[0][1] == pytest.approx(0.4, abs=1e-12)
    # The pause takes the first sample at or after the stop instant; the planner does not wait
    # at M0, so the grid point may lie a fraction of a period into the next move (< 1 nm here).
    assert samples[-1][1] == pytest.approx(0.410, abs=1e-9)
    assert "line 3" in stream.paused
    holds = [stream.next_sample() for _ in range(5)]
    assert all(h[1] == samples[-1][1] and h[2] == 0.0 for h in holds)
    # Program time stands still while paused: sample stamps go on, the program index does not.
    assert holds[-1][0] == (len(samples) + 4) * 10**6
    stream.paused = None
    rest = []
    while not stream.finished:
        rest.append(stream.next_sample())
    assert rest[-1][1] == pytest.approx(0.4, abs=1e-12)
    assert len(samples) + len(rest) == len(trajectory)


def test_program_stream_stop_waits_for_standstill() -> None:
    nc = load_nc_config(NC)
    trajectory = plan_program("G21 G90 G54\nG1 X10 F3000\nG1 X20\nM30\n", nc)
    stream = ProgramStream(trajectory, "X", period_ns=10**6, t0_ns=0, optional_stop=False)
    for _ in range(50):
        stream.next_sample()
    stream.stop_requested = True
    last = None
    while not stream.finished:
        last = stream.next_sample()
    assert last is not None, "the stream ended before its first sample after the stop request"
    assert stream.stopped
    assert abs(last[2]) < 1e-9  # at rest where it stopped
    assert stream.end_t_ns < len(trajectory) * 10**6


def test_summary_figures_from_columns() -> None:
    topics = AxisTopics(machine="cnc", axis="x")
    t = np.arange(0, 1000) * 1e-3
    e = 1e-5 * np.sin(2 * np.pi * 5 * t)
    run = {
        topics.state: {
            "header.stamp": t,
            "following_error": e,
            "i_d": np.zeros_like(t),
            "i_q": 3.0 * np.cos(2 * np.pi * t),
            "table_velocity": 0.1 * np.sin(2 * np.pi * t),
        },
        topics.command: {"header.stamp": t, "line": np.where(t < 0.5, 2, -1)},
    }
    summary = summarise(run, topics)
    assert summary.cycle_time_s == pytest.approx(0.499, abs=1e-12)
    window = t <= 0.499
    assert summary.following_error_rms_m == pytest.approx(np.sqrt(np.mean(e[window] ** 2)))
    assert summary.current_peak_A == pytest.approx(3.0)
    assert summary.velocity_peak_m_s == pytest.approx(0.1, rel=1e-4)
    with pytest.raises(ValueError, match=r"no /cnc/x/state messages: nothing was simulated"):
        summarise({topics.state: {}, topics.command: {}}, topics)


def test_program_stream_pause_request_waits_for_standstill() -> None:
    nc = load_nc_config(NC)
    trajectory = plan_program("G21 G90 G54\nG1 X10 F3000\nG4 P0.1\nG1 X20\nM30\n", nc)
    stream = ProgramStream(trajectory, "X", period_ns=10**6, t0_ns=0, optional_stop=False)
    for _ in range(50):
        stream.next_sample()
    stream.pause_requested = True
    last = None
    while stream.paused is None:
        last = stream.next_sample()
    assert last is not None, "the stream paused before its first sample after the request"
    assert stream.paused == "by request" and abs(last[2]) < 1e-9
    hold = stream.next_sample()
    assert (hold[1], hold[2], hold[4]) == (last[1], 0.0, stream.paused_line)


def test_delayed_reference_is_the_cubic_late() -> None:
    # Hermite through positions and velocities reproduces a cubic exactly: x(t - D_x) and
    # x'(t - D_v) for delays between samples, the acceleration (feed-forward) as it comes.
    period, D_x, D_v = 1e-3, 1.6875e-3, 2.6875e-3
    delayed = DelayedReference(period_s=period, position_delay_s=D_x, velocity_delay_s=D_v)

    def x(t: float) -> float:
        return 0.4 + 2.0 * t**3 - 0.5 * t**2

    def v(t: float) -> float:
        return 6.0 * t**2 - t

    first = delayed.update(x(0.0), 0.0, -1.0)
    assert first == (0.4, 0.0, -1.0)  # before the first sample: at rest where it starts
    for k in range(1, 12):
        t = k * period
        got = delayed.update(x(t), v(t), 12.0 * t - 1.0)
        if k >= 3:
            assert got[0] == pytest.approx(x(t - D_x), abs=1e-15)
            assert got[1] == pytest.approx(v(t - D_v), abs=1e-12)
            assert got[2] == 12.0 * t - 1.0
    delayed.reset()
    assert delayed.update(1.0, 2.0, 3.0) == (1.0, 0.0, 3.0)  # whole-period delays, at rest
    whole = DelayedReference(period_s=period, position_delay_s=0.0, velocity_delay_s=2e-3)
    whole.update(0.0, 0.5, 0.0)
    whole.update(1.0, 0.7, 0.0)
    assert whole.update(2.0, 0.9, 0.0) == (2.0, 0.5, 0.0)
    with pytest.raises(ValueError, match=r"period_s = 0.0: must be > 0"):
        DelayedReference(period_s=0.0, position_delay_s=0.0, velocity_delay_s=0.0)
    with pytest.raises(ValueError, match=r"velocity_delay_s = -0.001: must lie in \[0, 1\] s"):
        DelayedReference(period_s=period, position_delay_s=0.0, velocity_delay_s=-1e-3)


def test_feed_forward_delays_are_the_loops_lags() -> None:
    config = load_controller_config(yaml.safe_load(AXIS.read_text())["controller"], str(AXIS))
    D_x, D_v = feed_forward_delays(config, 1e-3)
    # one exchange of transport, half of hold, the current loop's 3 T_i; then the estimator's
    # half sample and the FIR's half sample at the exchange period: the velocity loop's T_sigma
    assert D_x == pytest.approx(1.5e-3 + 3 * 62.5e-6, rel=1e-12)
    assert D_v == pytest.approx(D_x + 1e-3, rel=1e-12)
    core = ControllerCore(config, boundary="torque", exchange_period_s=1e-3)
    assert any("feed-forward symmetrized" in n for n in core.notes)
    plain = ControllerCore(
        config,
        boundary="torque",
        exchange_period_s=1e-3,
        gains=NodeLoopGains(symmetrize_feed_forward=False),
    )
    assert not any("symmetrized" in n for n in plain.notes)
