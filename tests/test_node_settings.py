"""The node constructors' settings (feed_twin.nodeset.node_settings): read from the `ros:`
section, and every bad value refused naming its field."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from feed_twin.nodeset.config import load_node_set_config
from feed_twin.nodeset.node_settings import ControllerSettings, SimSettings, StandinSettings

AXIS = Path(__file__).resolve().parents[1] / "config" / "axis_default.yaml"


def test_settings_come_from_the_ros_section_and_the_command_line() -> None:
    ros = load_node_set_config(AXIS)
    sim = SimSettings.of(ros, realtime=True, max_time_s=2.0, clock_topic="/cnc/x/clock")
    assert (sim.joint_name, sim.axis_label, sim.settle_s) == (ros.axis, ros.axis.upper(),
                                                               ros.settle_s)  # fmt: skip
    assert (sim.realtime, sim.max_time_s, sim.clock_topic) == (True, 2.0, "/cnc/x/clock")
    assert sim.clock_divider == ros.clock_divider and sim.record_batch == ros.record_batch
    controller = ControllerSettings.of(ros, command_batch=True)
    assert controller.boundary == ros.boundary and controller.command_batch
    assert controller.exchange_period_s == ros.exchange_period_s


SIM = SimSettings(settle_s=0.2, joint_name="x", axis_label="X")
STANDIN = StandinSettings(period_s=1e-3, jitter_s=2e-4)
CONTROLLER = ControllerSettings(
    boundary="torque", exchange_period_s=1e-3, settle_s=0.2, axis_label="X"
)


@pytest.mark.parametrize(
    ("base", "changes", "message"),
    [
        (SIM, {"settle_s": -1.0}, "settle_s = -1.0: must be >= 0"),
        (SIM, {"joint_name": ""}, "joint_name = '': must not be empty"),
        (SIM, {"max_time_s": 0.0}, "max_time_s = 0.0: must be > 0"),
        (SIM, {"clock_divider": 0}, "clock_divider = 0: must be a whole number >= 1"),
        (SIM, {"exchange_cpu": -2}, "exchange_cpu = -2: must be a whole number >= -1"),
        (SIM, {"realtime_priority": 1.5}, "realtime_priority = 1.5: must be a whole number"),
        (SIM, {"record_batch": True}, "record_batch = True: must be a whole number >= 0"),
        (SIM, {"clock_topic": "clock"}, "clock_topic = 'clock': must be an absolute topic"),
        (CONTROLLER, {"exchange_period_s": 0.0}, "exchange_period_s = 0.0: must be > 0"),
        (CONTROLLER, {"axis_label": ""}, "axis_label = '': must not be empty"),
        (CONTROLLER, {"record_batch": -1}, "record_batch = -1: must be a whole number >= 0"),
        (STANDIN, {"period_s": 0.0}, "period_s = 0.0: must be > 0"),
        (STANDIN, {"jitter_s": -1e-4}, "jitter_s = -0.0001: must be >= 0"),
        (STANDIN, {"seed": -1}, "seed = -1: must be a whole number >= 0"),
        (STANDIN, {"clock_topic": "x/clock"}, "clock_topic = 'x/clock': must be an absolute"),
    ],
)
def test_a_bad_setting_is_refused_naming_its_field(base, changes, message) -> None:
    with pytest.raises(ValueError, match=f"^{message}"):
        dataclasses.replace(base, **changes)
