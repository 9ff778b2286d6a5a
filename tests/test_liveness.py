"""A slow node is not a dead one: the verdict on a silent peer from its beat and its process."""

from __future__ import annotations

import os
import signal
import socket
import subprocess

import pytest

from feed_twin.nodeset.liveness import (
    Beat,
    heartbeat_text,
    parse_heartbeat,
    process_lives,
    silence_verdict,
)

HOST = socket.gethostname()


def test_a_beat_names_role_process_and_host() -> None:
    beat = parse_heartbeat(heartbeat_text("twin"))
    assert beat == Beat(role="twin", pid=os.getpid(), host=HOST)
    # a bare role (a node that does not name its process) has none
    assert parse_heartbeat("sim") == Beat(role="sim", pid=None, host=None)


def _dead_pid() -> int:
    child = subprocess.Popen(["sleep", "10"])
    child.kill()
    child.wait()  # reaped: the pid is free
    return child.pid


def _zombie_pid() -> tuple[int, subprocess.Popen]:
    child = subprocess.Popen(["sleep", "10"])
    os.kill(child.pid, signal.SIGKILL)
    # not waited for: a zombie until the parent reaps it
    for _ in range(200):
        if not process_lives(child.pid):
            break
        os.sched_yield()
    return child.pid, child


def test_process_lives() -> None:
    assert process_lives(os.getpid())
    assert not process_lives(_dead_pid())
    pid, child = _zombie_pid()
    try:
        assert os.path.exists(f"/proc/{pid}")  # still there, as a zombie
        assert not process_lives(pid)
    finally:
        child.wait()


@pytest.mark.parametrize(
    ("beat", "silent_s", "verdict"),
    [
        (Beat(role="twin", pid=os.getpid(), host=HOST), 0.5, "ok"),
        # silent past the timeout, its process lives here: slow, the run goes on
        (Beat(role="twin", pid=os.getpid(), host=HOST), 1.2, "slow"),
        (Beat(role="twin", pid=os.getpid(), host=HOST), 61.0, "hung"),
        # its process is dead: gone at the timeout
        (Beat(role="twin", pid=_dead_pid(), host=HOST), 0.9, "gone"),
        # nothing to look at: the silence alone decides
        (Beat(role="twin", pid=os.getpid(), host="another-host"), 0.9, "gone"),
        (Beat(role="twin", pid=None, host=None), 0.9, "gone"),
        (None, 0.9, "gone"),
    ],
)
def test_silence_verdict(beat: Beat | None, silent_s: float, verdict: str) -> None:
    assert silence_verdict(beat, silent_s, timeout_s=0.8, hung_s=60.0) == verdict


def test_the_runner_names_slow_nodes_from_the_logs(tmp_path) -> None:
    from feed_twin.ros.launch import slow_line, slow_nodes

    (tmp_path / "sim.log").write_text(
        "[WARN] [1.0] [cnc.x.sim]: node '/cnc/x/gcode' is slow: no heartbeat for 0.81 s, its "
        "process lives (a busy host); the run goes on (hung after 60 s)\n"
    )
    (tmp_path / "twin.log").write_text(
        "[WARN] [1.2] [cnc.x.twin]: node '/cnc/x/gcode' is slow: no heartbeat for 1.30 s, its "
        "process lives\n[WARN] [1.3] [cnc.x.twin]: node '/cnc/x/sim' is slow: no heartbeat for "
        "0.90 s, its process lives\n"
    )
    assert slow_nodes(tmp_path) == {"/cnc/x/gcode": 1.3, "/cnc/x/sim": 0.9}
    assert slow_line(tmp_path) == (
        "slow, not gone (the run went on): '/cnc/x/gcode' (1.30 s without heartbeat), "
        "'/cnc/x/sim' (0.90 s without heartbeat)"
    )
    assert slow_line(tmp_path / "empty") is None
