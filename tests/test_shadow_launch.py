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
