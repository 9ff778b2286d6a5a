"""A slow node is not a dead one: the verdict on a silent peer from its beat and its process."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feed_twin.nodeset.liveness import (
    HEARTBEAT_PERIOD_S,
    Beat,
    JitterMeter,
    PeerState,
    heartbeat_text,
    parse_heartbeat,
    process_lives,
    verdict,
)
from feed_twin.ros.domain import private_graph_env, reserve_domain_id

HOST = socket.gethostname()


def test_a_beat_names_role_process_host_and_progress() -> None:
    beat = parse_heartbeat(heartbeat_text("twin", 42))
    assert beat == Beat(role="twin", pid=os.getpid(), host=HOST, turns=42)
    # a beat without its progress, and a bare role (a node that does not name its process)
    assert parse_heartbeat(heartbeat_text("twin")) == Beat(role="twin", pid=os.getpid(), host=HOST)
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


ME = Beat(role="twin", pid=os.getpid(), host=HOST, turns=7)


@pytest.mark.parametrize(
    ("beat", "silent_s", "still_s", "said"),
    [
        (ME, 0.05, 0.5, "ok"),
        # no progress past the tolerance, its process lives here: slow, the run goes on
        (ME, 1.2, 1.2, "slow"),
        (ME, 0.05, 1.2, "slow"),  # it beats, its loop does not turn
        (ME, 61.0, 61.0, "hung"),
        (ME, 0.05, 61.0, "hung"),
        # its process is dead: gone once past the floor, whatever the jitter allows
        (Beat(role="twin", pid=_dead_pid(), host=HOST), 0.9, 0.9, "gone"),
        (Beat(role="twin", pid=_dead_pid(), host=HOST), 0.5, 0.5, "ok"),
        # nothing to look at: the silence alone decides, past the tolerance
        (Beat(role="twin", pid=os.getpid(), host="another-host"), 1.6, 1.6, "gone"),
        (Beat(role="twin", pid=os.getpid(), host="another-host"), 1.2, 1.2, "ok"),
        (Beat(role="twin", pid=os.getpid(), host="another-host"), 0.05, 1.6, "slow"),
        (Beat(role="twin", pid=None, host=None), 1.6, 1.6, "gone"),
        (None, 1.6, 1.6, "gone"),
    ],
)
def test_verdict(beat: Beat | None, silent_s: float, still_s: float, said: str) -> None:
    peer = PeerState(beat=beat, silent_s=silent_s, still_s=still_s)
    assert verdict(peer, floor_s=0.8, tolerance_s=1.5 if beat is not ME else 0.8, hung_s=60.0) == (
        said
    )


def test_the_tolerance_follows_the_worst_recent_lateness() -> None:
    meter = JitterMeter(window_s=30.0)
    assert meter.tolerance_s(0.8) == 0.8  # nothing measured: the floor
    for k in range(500):  # a quiet host: 20 ms wake-ups a millisecond late
        meter.add(100.0 + 0.02 * k, 0.001)
    assert meter.tolerance_s(0.8) == 0.8
    meter.add(110.0, 1.5)  # a stall of 1.5 s
    assert meter.tolerance_s(0.8) == pytest.approx(HEARTBEAT_PERIOD_S + 2.0 * 1.5)
    meter.add(135.0, 0.002)  # within the window the stall still counts
    assert meter.tolerance_s(0.8) == pytest.approx(3.1)
    meter.add(141.5, 0.002)  # out of it: the floor again
    assert meter.tolerance_s(0.8) == 0.8
    assert meter.worst_s == 1.5
    assert meter.count == 503
    meter.add(142.0, -0.01)  # early counts as on time
    assert meter.recent_s() == 0.002


def test_a_jitter_window_must_be_positive() -> None:
    with pytest.raises(ValueError, match=r"window_s = 0\.0: must be > 0"):
        JitterMeter(window_s=0.0)


def test_the_runner_names_slow_nodes_from_the_logs(tmp_path) -> None:
    from feed_twin.ros.launch import slow_line, slow_nodes

    (tmp_path / "sim.log").write_text(
        "[WARN] [1.0] [cnc.x.sim]: node '/cnc/x/gcode' is slow: no progress for 0.81 s (no "
        "heartbeat for 0.81 s; tolerance 0.80 s from this host's jitter), its process lives (a "
        "busy host); the run goes on (hung after 60 s)\n"
    )
    (tmp_path / "twin.log").write_text(
        "[WARN] [1.2] [cnc.x.twin]: node '/cnc/x/gcode' is slow: no progress for 1.30 s (no "
        "heartbeat for 1.30 s; ...), its process lives\n[WARN] [1.3] [cnc.x.twin]: node "
        "'/cnc/x/sim' is slow: no progress for 0.90 s (no heartbeat for 0.50 s; ...)\n[WARN] "
        "[1.4] [cnc.x.twin]: node '/cnc/x/sim' is slow: no progress for 1.10 s (it beats, its "
        "loop does not turn; tolerance 0.80 s)\n[INFO] [1.9] [cnc.x.twin]: node '/cnc/x/sim' "
        "moves again after 1.60 s\n"
    )
    assert slow_nodes(tmp_path) == {"/cnc/x/gcode": 1.3, "/cnc/x/sim": 1.6}
    assert slow_line(tmp_path) == (
        "slow, not gone (the run went on): '/cnc/x/gcode' (1.30 s without progress), "
        "'/cnc/x/sim' (1.60 s without progress)"
    )
    assert slow_line(tmp_path / "empty") is None


PEER = Path(__file__).with_name("liveness_peer.py")
HOLD_S = 2.0  # [s] past the floor of the tolerance (0.8 s), far below hung_s


def _wait_for(log: Path, text: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text(errors="replace"):
        assert time.monotonic() < deadline, f"no {text!r} in {log}: {log.read_text()[-2000:]}"
        time.sleep(0.05)


@pytest.mark.ros
@pytest.mark.slow
def test_slow_and_gone_are_told_apart_on_real_nodes(tmp_path: Path) -> None:
    """Three node processes watch each other. One is stopped (SIGSTOP) for 2 s, then holds its
    own loop 2 s while its beat thread goes on: both times slow, said once each, and the run
    goes on; the stopped one does not blame its peers for the beats it did not take. A hold in a
    wait the node knows of is not slow. Then one is killed: gone, within the bound."""
    flag = tmp_path / "hold"
    roles = ("a", "b", "c")
    logs = {role: tmp_path / f"{role}.log" for role in roles}
    procs: dict[str, subprocess.Popen] = {}
    with reserve_domain_id() as domain:
        env = {**os.environ, **private_graph_env(domain.domain_id)}
        try:
            for role in roles:
                peers = ",".join(r for r in roles if r != role)
                hold = flag if role == "b" else tmp_path / "never"
                with open(logs[role], "w") as out:
                    procs[role] = subprocess.Popen(
                        [sys.executable, str(PEER), role, peers, str(hold), str(HOLD_S)],
                        stdout=out, stderr=subprocess.STDOUT, env=env,
                    )  # fmt: skip
            for role in roles:
                _wait_for(logs[role], "SEEN")
            time.sleep(0.5)
            os.kill(procs["b"].pid, signal.SIGSTOP)
            time.sleep(HOLD_S)
            os.kill(procs["b"].pid, signal.SIGCONT)
            _wait_for(logs["a"], "node '/lv/x/b' moves again after", 10.0)
            flag.write_text("waiting")  # a wait it knows of: not slow
            _wait_for(logs["b"], "HELD", 10.0)
            flag.touch()
            _wait_for(logs["b"], "HELD\nHELD", 10.0)
            _wait_for(logs["a"], "moves again after", 10.0)
            time.sleep(0.5)
            procs["c"].kill()
            killed_at = time.monotonic()
            code_a = procs["a"].wait(timeout=20.0)
            ended_s = time.monotonic() - killed_at
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                proc.wait(timeout=10.0)
    a, b = logs["a"].read_text(), logs["b"].read_text()
    said = re.findall(
        r"node '/lv/x/b' is slow: no progress for (\S+) s \((no heartbeat|it beats)", a
    )
    assert [kind for _, kind in said] == ["no heartbeat", "it beats"], a
    assert all(float(s) < HOLD_S for s, _ in said)  # said while it lasted, not after
    assert "(it beats, its loop does not turn; tolerance " in a
    assert a.count("node '/lv/x/b' moves again after") == 2
    assert "'/lv/x/b' is gone" not in a
    assert "is slow" not in b, b  # its own stop explains the silence of its peers
    # the killed one is gone within the floor and a beat or two
    assert code_a == 3, a
    gone = re.search(r"node '/lv/x/c' is gone: no heartbeat for (\S+) s", a)
    assert gone is not None, a
    assert float(gone[1]) < 1.5
    assert ended_s < 5.0


@pytest.mark.ros
def test_a_node_pays_its_first_log_call_at_set_up() -> None:
    """rclpy's logger finds its caller through inspect, whose first call reads every loaded
    module's path (seconds on a loaded host): warmed up at set-up, never mid-run."""
    script = (
        "import inspect, os, sys\n"
        "from feed_twin.ros import runtime\n"
        "before = len(inspect.modulesbyfile)\n"
        "runtime.warm_up_logging()\n"
        "print(before, os.path.realpath(runtime.__file__) in inspect.modulesbyfile,"
        " len(inspect.modulesbyfile) > len(sys.modules) // 2)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.stdout.split() == ["0", "True", "True"], done.stderr
