"""The G-code node's program control over ROS: M0 pauses, the start service resumes; and the
real-time mode's pacing and report."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from nodes_support import AXIS_CONFIG, Operator, last_json, start_run, wait_for

from feed_twin.io.bag import BagReader
from feed_twin.nodeset.config import load_node_set_config
from feed_twin.nodeset.pacing import setpoint_priority

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PAUSING = "%\nG21 G90 G54 G64\nG1 X10 F3000\nM0\nG1 X0\nM30\n%\n"


def test_m0_pauses_and_the_start_service_resumes(tmp_path: Path, ros_domain_id: int) -> None:
    config = AXIS_CONFIG
    program = tmp_path / "pause.ngc"
    program.write_text(PAUSING)
    logs = tmp_path / "bags" / "pause.logs"
    with Operator(ros_domain_id) as operator:
        proc = start_run(
            [str(program), "--config", str(config), "--out", str(tmp_path / "bags"),
             "--name", "pause", "--json"],
            ros_domain_id,
        )  # fmt: skip
        try:
            wait_for(logs / "gcode.log", r"program: paused line 4 \(M0\)", proc)
            time.sleep(1.0)  # the axis holds at the pause for a while (simulated time goes on)
            assert operator.press("/cnc/x/gcode/start", timeout_s=20.0) == "resumed"
            out, err = proc.communicate(timeout=180)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    record = last_json(out)
    command = BagReader(record["bag"]).columns("/cnc/x/command", ["position", "velocity", "line"])
    held = (command["line"] == 4) & (command["velocity"] == 0.0)
    # Held at the end of the first move for the whole pause (more than half a second of
    # simulated time, since the node paused within ~0.1 s and was resumed 1 s later).
    assert held.sum() > 500
    np.testing.assert_allclose(command["position"][held], 0.410, atol=1e-9)  # machine X
    state = BagReader(record["bag"]).columns("/cnc/x/state", ["table_position"])
    assert state["table_position"][-1] == pytest.approx(0.4, abs=2e-6)


def test_realtime_mode_paces_and_reports_lateness(tmp_path: Path, ros_domain_id: int) -> None:
    config = AXIS_CONFIG
    program = tmp_path / "short.ngc"
    program.write_text("%\nG21 G90 G54\nG1 X5 F3000\nG4 P1.0\nM30\n%\n")
    proc = start_run(
        [str(program), "--config", str(config), "--out", str(tmp_path / "bags"),
         "--name", "rt", "--json", "--realtime"],
        ros_domain_id,
    )  # fmt: skip
    try:
        out, err = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    record = last_json(out)
    assert record["exit_code"] == 0, err
    # Paced by the wall clock: simulated and wall time agree (the exchanges start on time even
    # when a DriveCommand comes late; those count as missed steps).
    assert record["timing_wall_time_s"] == pytest.approx(record["timing_sim_time_s"], rel=0.05)
    assert record["timing_lateness_p50_ms"] <= record["timing_lateness_p99_ms"]
    assert record["timing_lateness_p99_ms"] <= record["timing_lateness_max_ms"]
    assert 0 <= record["timing_missed_steps"] <= record["timing_steps"]
    assert "lateness_p99_ms" in out and "missed steps" in out
    # the setpoints the controller waits for come from a node one priority below the exchange
    # (feed_twin.nodeset.pacing.setpoint_priority; granted or refused, it is asked for)
    priority = setpoint_priority(load_node_set_config(config).realtime_priority)
    gcode_log = (Path(record["logs"]) / "gcode.log").read_text()
    assert f"scheduling: SCHED_FIFO priority {priority}" in gcode_log or (
        f"scheduling: normal scheduling, SCHED_FIFO priority {priority} refused" in gcode_log
    ), gcode_log[-2000:]
