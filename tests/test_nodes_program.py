"""The G-code node's program control over ROS: M0 pauses, the start service resumes; and the
real-time mode's pacing and report."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from nodes_support import AXIS_CONFIG, last_json, start_run
from std_srvs.srv import Trigger

from feed_twin.io.bag import BagReader
from feed_twin.ros.dds import init_context

pytestmark = [pytest.mark.ros, pytest.mark.slow]
PAUSING = "%\nG21 G90 G54 G64\nG1 X10 F3000\nM0\nG1 X0\nM30\n%\n"


def wait_for(path: Path, pattern: str, proc, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.stderr.read()}")
        if path.exists() and re.search(pattern, path.read_text(errors="replace")):
            return
        time.sleep(0.1)
    raise AssertionError(f"{pattern!r} did not appear in {path}")


def test_m0_pauses_and_the_start_service_resumes(tmp_path: Path, ros_domain_id: int) -> None:
    config = AXIS_CONFIG
    program = tmp_path / "pause.ngc"
    program.write_text(PAUSING)
    logs = tmp_path / "bags" / "pause.logs"
    proc = start_run(
        [str(program), "--config", str(config), "--out", str(tmp_path / "bags"),
         "--name", "pause", "--json"],
        ros_domain_id,
    )  # fmt: skip
    context = init_context()
    node = context and __import__("rclpy").create_node("pause_test", context=context)
    try:
        wait_for(logs / "gcode.log", r"program: paused line 4 \(M0\)", proc)
        time.sleep(1.0)  # the axis holds at the pause for a while (simulated time goes on)
        client = node.create_client(Trigger, "/cnc/x/gcode/start")
        assert client.wait_for_service(timeout_sec=20.0)
        future = client.call_async(Trigger.Request())
        deadline = time.monotonic() + 20.0
        executor = __import__("rclpy").executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        while not future.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert future.done() and future.result().success
        assert future.result().message == "resumed"
        out, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
        node.destroy_node()
        context.try_shutdown()
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
