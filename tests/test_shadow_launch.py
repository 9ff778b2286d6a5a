"""`launch.launch`, the process launcher of `feed-twin run`, `run --shadow` and `feed-twin
shadow`, with plain processes (no ROS): a failing process ends the run and is named with its
last error, and a deadline stops processes that would run for ever."""

from __future__ import annotations

import os
import sys
import time

from feed_twin.ros.launch import launch

PY = sys.executable


def test_deadline_stops_every_process_and_says_so(tmp_path) -> None:
    started = time.monotonic()
    result = launch(
        {
            "slow": [PY, "-c", "import time; time.sleep(60)"],
        },
        tmp_path,
        env=dict(os.environ),
        deadline_s=0.5,
    )
    assert time.monotonic() - started < 5.0  # told to stop (SIGTERM) at the deadline
    assert result.code == 1
    assert result.reason == "the run took longer than 0.5 s; every node was stopped"
    assert all(code is not None for code in result.returncodes.values())


def test_a_failing_process_is_named_with_its_last_error(tmp_path) -> None:
    result = launch(
        {
            "ok": [PY, "-c", "import time; time.sleep(0.3)"],
            "bad": [PY, "-c", "import sys; print('[ERROR] the axis is on fire'); sys.exit(4)"],
        },
        tmp_path,
        env=dict(os.environ),
    )
    assert result.code == 4
    assert result.reason.startswith("bad node exited with code 4: [ERROR] the axis is on fire")
    assert (tmp_path / "bad.log").read_text().strip() == "[ERROR] the axis is on fire"


def _logs_with_rclpy(logger: str, message: str, then: str) -> list[str]:
    """A process that logs `message` through rclpy's own logger `logger` (its console format,
    as a node /cnc/x/sim writes it) and then runs `then`."""
    said = f"rclpy.logging.get_logger({logger!r}).error({message!r})"
    return [PY, "-c", f"import os, rclpy.logging, sys, time; {said}; sys.stderr.flush(); {then}"]


FAULT = (
    "drive fault 1 at t = 4.7500 s: following error 2.000 mm exceeds the limit 2.000 mm "
    "(controller.position.following_error_limit_m)"
)


def test_a_failed_node_is_named_by_its_namespace_without_the_log_prefix(tmp_path) -> None:
    message = f"{FAULT}\n  last setpoint 12.000 mm"
    result = launch(
        {
            "sim": _logs_with_rclpy("cnc.x.sim", message, "sys.exit(1)"),
            "x_nodes": _logs_with_rclpy(
                "cnc.x.controller", "lost sim", "time.sleep(0.3); sys.exit(3)"
            ),
        },
        tmp_path,
        env=dict(os.environ),
    )
    assert result.code == 1
    assert "[ERROR] [" in (tmp_path / "sim.log").read_text()  # the log keeps rclpy's prefix
    # the first failure, then what the others said; a process named for none of its nodes
    # (a node host) names the node that spoke
    assert result.reason == (
        f"sim node (cnc/x) exited with code 1: {FAULT}\n    last setpoint 12.000 mm"
        "\n  x_nodes node (cnc/x/controller) exited with code 3: lost sim"
    )


def test_a_killed_node_says_what_it_had_logged(tmp_path) -> None:
    result = launch(
        {"sim": _logs_with_rclpy("cnc.x.sim", FAULT, "os.kill(os.getpid(), 9)")},
        tmp_path,
        env=dict(os.environ),
    )
    assert result.reason == f"sim node (cnc/x) was killed by SIGKILL (it had said: {FAULT})"


def test_a_node_that_said_no_error_is_not_named_by_its_last_line(tmp_path) -> None:
    info = "import rclpy.logging, sys; rclpy.logging.get_logger('cnc.x.controller').info('up')"
    result = launch(
        {"controller": [PY, "-c", f"{info}; sys.exit(2)"]}, tmp_path, env=dict(os.environ)
    )
    assert result.reason == "controller node exited with code 2: up"
