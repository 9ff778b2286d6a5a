"""Measured data from a rosbag2 recording: topics and fields mapped like CSV columns."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from feed_twin.io.bag import BagWriter
from feed_twin.io.measured import MeasuredDataError, load_measured

MAP = """\
time: {column: "/axis/joint_states:header.stamp", unit: s}
position_sensor: motor_encoder
signals:
  pos_meas_m: {column: "/axis/joint_states:position[0]", unit: m}
  force_cmd_N: {column: "/axis/joint_states:effort[0]", unit: N}
  pos_cmd_m: {column: "/axis/command:position[0]", unit: mm}
plausibility: {travel_m: 0.5, max_speed_m_s: 1.0}
"""


def _state(t: float, x: float, f: float) -> bytes:
    msg = JointState()
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))
    msg.name = ["x"]
    msg.position = [x]
    msg.velocity = [0.0]
    msg.effort = [f]
    return bytes(serialize_message(msg))


def _write_bag(path: Path, n: int = 600, h: float = 1e-3, burst: int = 1) -> dict[str, np.ndarray]:
    """A state and a command topic; with `burst` > 1 the recorder logs them in bursts of that
    many messages, as it does for a lockstep run (simulation-time stamps, wall-clock arrival)."""
    t = 10.0 + h * np.arange(n)
    x = 0.05 * np.sin(2 * np.pi * 1.5 * (t - t[0]))
    f = 30.0 * np.cos(2 * np.pi * 1.5 * (t - t[0]))
    with BagWriter(path, flush_period_s=None) as bag:
        bag.add_topic("/axis/joint_states", "sensor_msgs/msg/JointState")
        bag.add_topic("/axis/command", "sensor_msgs/msg/JointState")
        for k in range(n):
            ns = int(round(t[k - k % burst] * 1e9))
            bag.write("/axis/joint_states", _state(t[k], x[k], f[k]), log_time_ns=ns + 200_000)
            # the command topic arrives half a period later, in mm
            bag.write(
                "/axis/command",
                _state(t[k], 1e3 * (x[k] + 1e-5), 0.0),
                log_time_ns=ns + 700_000,
            )
    return {"t": t, "x": x, "f": f}


def test_bag_columns_become_canonical_signals(tmp_path):
    truth = _write_bag(tmp_path / "run")
    (tmp_path / "map.yaml").write_text(MAP)
    run = load_measured(tmp_path / "run", tmp_path / "map.yaml")
    np.testing.assert_allclose(run.t_s, truth["t"], atol=1e-9)
    np.testing.assert_allclose(run["pos_meas_m"], truth["x"], atol=1e-12)
    np.testing.assert_allclose(run["force_cmd_N"], truth["f"], atol=1e-9)
    # the command topic is resampled onto the state topic's base by its header stamps: its
    # 0.5 ms later arrival does not shift it
    np.testing.assert_allclose(run["pos_cmd_m"], truth["x"] + 1e-5, rtol=0, atol=1e-12)


def test_a_lockstep_bag_is_lined_up_by_its_stamps_not_by_arrival(tmp_path):
    truth = _write_bag(tmp_path / "run", burst=25)
    (tmp_path / "map.yaml").write_text(MAP)
    run = load_measured(tmp_path / "run", tmp_path / "map.yaml")
    # by arrival, 25 commands would share one receive time (a 25 ms staircase, and speeds far
    # beyond the axis); by their stamps they fall where they belong
    np.testing.assert_allclose(run["pos_cmd_m"], truth["x"] + 1e-5, rtol=0, atol=1e-12)


def test_bag_missing_topic_is_named(tmp_path):
    _write_bag(tmp_path / "run", n=300)
    (tmp_path / "map.yaml").write_text(MAP.replace("/axis/command", "/axis/cmd"))
    with pytest.raises(MeasuredDataError, match=r"names topic '/axis/cmd', which the bag lacks"):
        load_measured(tmp_path / "run", tmp_path / "map.yaml")


def test_bag_column_without_topic_is_refused(tmp_path):
    _write_bag(tmp_path / "run", n=300)
    (tmp_path / "map.yaml").write_text(MAP.replace('"/axis/joint_states:effort[0]"', "effort"))
    with pytest.raises(MeasuredDataError, match=r"map column 'effort' must read '<topic>:<field>'"):
        load_measured(tmp_path / "run", tmp_path / "map.yaml")
