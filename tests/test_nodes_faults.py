"""Faults of the node set: a killed node, a signal to the runner, a bad program, a wrong topic."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from nodes_support import AXIS_CONFIG, ROOT, found, last_json, node_env, run, start_run

from feed_twin.io.bag import BagReader, info
from feed_twin.ros.domain import reserve_domain_id
from feed_twin.ros.exit_timer import exit_after

pytestmark = [pytest.mark.ros, pytest.mark.slow]
SAMPLE = ROOT / "tests" / "fixtures" / "gcode" / "sample.ngc"  # about 7 s of motion
# Processes of a run: by default the recorder records inside the sim's process
# (ros.recorder_host: auto in lockstep, feed_twin/ros/host.py); with "own" it has its own.
PROCESSES = ("sim", "controller", "gcode")
PROCESSES_OWN_RECORDER = (*PROCESSES, "recorder")


@pytest.fixture(scope="module")
def config(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A private copy of the axis config: its path tells this run's processes apart, and the
    bags land beside it (never in the repository)."""
    path = tmp_path_factory.mktemp("faults") / "axis.yaml"
    shutil.copyfile(AXIS_CONFIG, path)
    return path


@pytest.fixture(scope="module")
def config_own_recorder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("faults_own") / "axis.yaml"
    text = AXIS_CONFIG.read_text()
    assert "recorder_host: auto " in text
    path.write_text(text.replace("recorder_host: auto ", "recorder_host: own "))
    return path


def node_pids(config: Path) -> dict[str, int]:
    """PIDs of this run's node processes by name (found by their module, or the first role a
    node host runs, and this test's config path)."""
    found: dict[str, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        text = [a.decode(errors="replace") for a in argv]
        if str(config) not in text:
            continue
        for i, arg in enumerate(text):
            if arg == "feed_twin.ros.host" and i + 1 < len(text):
                found[text[i + 1]] = int(entry.name)
            elif arg.startswith("feed_twin.ros.") and arg.endswith("_node"):
                found[arg.removeprefix("feed_twin.ros.").removesuffix("_node")] = int(entry.name)
    return found


def wait_for_progress(
    proc: subprocess.Popen, log: Path, sim_s: float, timeout_s: float = 120.0
) -> None:
    assert proc.stderr is not None, "the run is started with stderr=PIPE"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.stderr.read()}")
        if log.exists():
            values = re.findall(r"PROGRESS (\S+)", log.read_text(errors="replace"))
            if values and float(values[-1]) >= sim_s:
                return
        time.sleep(0.1)
    raise AssertionError(f"the run did not reach {sim_s} s of simulated time")


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().split()[2] != "Z"


def start_sample_run(config: Path, name: str, domain_id: int) -> subprocess.Popen:
    out = config.parent / "bags"
    return start_run(
        [str(SAMPLE), "--config", str(config), "--out", str(out), "--name", name, "--json"],
        domain_id,
    )


@pytest.mark.parametrize("victim", PROCESSES_OWN_RECORDER)
def test_killed_node_is_noticed_named_and_bag_readable(
    config: Path, config_own_recorder: Path, victim: str
) -> None:
    """Kill one process: every other notices within a second and names the node(s) it lost.
    The recorder-only victim runs with the recorder in a process of its own; killing the sim's
    process kills the recorder in it too, and the runner recovers the bag."""
    if victim == "recorder":
        config = config_own_recorder
    processes = PROCESSES_OWN_RECORDER if victim == "recorder" else PROCESSES
    name = f"kill_{victim}"
    logs = config.parent / "bags" / f"{name}.logs"
    with reserve_domain_id() as domain:
        proc = start_sample_run(config, name, domain.domain_id)
        try:
            # the sim's process holds the recorder: let it flush a few times before the kill
            wait_for_progress(proc, logs / "sim.log", 3.0 if victim == "sim" else 0.5)
            pids = node_pids(config)
            assert set(pids) == set(processes), pids
            os.kill(pids[victim], signal.SIGKILL)
            killed_at = time.monotonic()
            others = {r: p for r, p in pids.items() if r != victim}
            ended: dict[str, float] = {}
            while len(ended) < len(others) and time.monotonic() - killed_at < 40.0:
                for role, pid in others.items():
                    if role not in ended and not alive(pid):
                        ended[role] = time.monotonic() - killed_at
                time.sleep(0.02)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    assert proc.returncode != 0
    # named either by the peers (no heartbeat) or, when the launcher sees the exit first, by
    # the launcher with the signal: both name the killed node and nothing else
    gone = f"node '/cnc/x/{victim}' is gone"
    assert gone in err or f"{victim} node was killed by SIGKILL" in err, err
    # Every other node noticed by itself (no heartbeat for 0.8 s) and ended promptly.
    for role in others:
        text = (logs / f"{role}.log").read_text(errors="replace")
        if victim == "recorder" and "ended: run done" in text and gone not in text:
            # the recorder is outside the control loop: a fast node set may finish the program
            # before its peer timeout names the lost recorder (the launcher named it, above)
            continue
        assert gone in text, role
        if victim == "sim":  # the recorder in its process is named with it
            assert "node '/cnc/x/recorder' is gone" in text, role
        assert float(found(r"is gone: no heartbeat for (\S+) s", text)[1]) < 1.0
        # The recorder first records what is still in flight (it may lag on a loaded machine).
        assert ended[role] < (30.0 if role == "recorder" else 5.0), (role, ended)
    bag = config.parent / "bags" / name
    summary = info(bag)  # finished by the recorder, or recovered by the runner
    counts = {t.name: t.message_count for t in summary.topics}
    states = BagReader(bag).columns("/cnc/x/state", ["header.stamp"])["header.stamp"]
    assert states.size == counts["/cnc/x/state"] > 0
    # What was recorded is the run from its start without a gap (a killed recorder loses only
    # its unflushed tail: at most one flush period plus what it had not yet received).
    np.testing.assert_allclose(np.diff(states), 1e-3, atol=1e-9)
    if victim != "recorder":
        assert states.size > 300


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_stops_every_node_and_finalises_the_bag(config: Path, signum: int) -> None:
    name = f"signal_{signal.Signals(signum).name}"
    logs = config.parent / "bags" / f"{name}.logs"
    with reserve_domain_id() as domain:
        proc = start_sample_run(config, name, domain.domain_id)
        try:
            wait_for_progress(proc, logs / "sim.log", 0.5)
            pids = node_pids(config)
            proc.send_signal(signum)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    assert proc.returncode == 130
    assert f"stopped by {signal.Signals(signum).name}" in err
    assert not any(alive(pid) for pid in pids.values())
    bag = config.parent / "bags" / name
    assert (bag / "metadata.yaml").exists()  # closed by the recorder, not recovered
    recorder_log = (logs / "sim.log").read_text()  # the recorder runs in the sim's process
    assert "recorder: " in recorder_log
    assert f"stopped by {signal.Signals(signum).name}" in recorder_log
    summary = info(bag)
    counts = {t.name: t.message_count for t in summary.topics}
    # Nothing lost up to the stop: every exchange the sim made is in the bag.
    steps = int(found(r'"steps": (\d+)', (logs / "sim.log").read_text())[1])
    assert counts["/cnc/x/state"] == steps


def test_gcode_error_stops_before_motion(config: Path, tmp_path: Path) -> None:
    program = tmp_path / "bad.ngc"
    program.write_text("G21 G90\nG1 X10 F3000\nG93 G1 X20 F2\n")
    with reserve_domain_id() as domain:
        code, out, err = run(
            [str(program), "--config", str(config), "--out", str(tmp_path / "bags"), "--json"],
            domain.domain_id,
        )
    assert code == 1
    assert re.search(r"G-code error, nothing was started: .*bad\.ngc:3:1: word 'G93'", err), err
    assert last_json(out)["reason"] in err
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())


WRONG_STREAM = """
import sys, time
from feed_twin.ros.dds import init_context
from rclpy.node import Node
from rclpy.experimental import EventsExecutor
from {module} import {cls}
ctx = init_context()
node = Node("external_nc", context=ctx)
pub = node.create_publisher({cls}, "{topic}", 10)
ex = EventsExecutor(context=ctx)
ex.add_node(node)
print("ready", flush=True)
while True:
    pub.publish({cls}())
    ex.spin_once(timeout_sec=0.01)
"""


@pytest.mark.parametrize(
    ("module", "cls", "topic", "expected"),
    [
        (
            "feed_twin_msgs.msg",
            "AxisCommand",
            "/cnc/y/command",
            r"feed_twin_msgs/msg/AxisCommand is published on: /cnc/y/command \(wrong namespace\?\)",
        ),
        (
            "std_msgs.msg",
            "Float64",
            "/cnc/x/command",
            r"/cnc/x/command is published with type std_msgs/msg/Float64 instead",
        ),
    ],
)
def test_missing_or_mistyped_command_stream_is_reported(
    config: Path, tmp_path: Path, module: str, cls: str, topic: str, expected: str
) -> None:
    with reserve_domain_id() as domain:
        source = WRONG_STREAM.format(module=module, cls=cls, topic=topic)
        external = subprocess.Popen(
            [sys.executable, "-c", source],
            env=node_env(domain.domain_id),
            stdout=subprocess.PIPE,
            text=True,
        )
        assert external.stdout is not None, "started with stdout=PIPE"
        try:
            assert external.stdout.readline().strip() == "ready"
            code, out, err = run(
                [
                    "--no-gcode", "--config", str(config), "--out", str(tmp_path / "bags"),
                    "--input-timeout", "2", "--max-time", "30",
                ],
                domain.domain_id,
            )  # fmt: skip
        finally:
            external.kill()
            external.wait(timeout=10)
    assert code == 4, err
    assert "no feed_twin_msgs/msg/AxisCommand message on /cnc/x/command for 2 s" in err
    assert re.search(expected, err), err


def test_a_teardown_that_holds_the_gil_ends_the_node_process_with_its_code() -> None:
    """A teardown spinning in C with the GIL held (rclpy's events executor waiting for a DDS
    thread that waits for the GIL) stops every Python thread; the process still ends with its
    nodes' code, from libc's timer thread, one second after the limit."""
    script = (
        "import ctypes\n"
        "from feed_twin.ros.runtime import exit_if_teardown_hangs\n"
        "exit_if_teardown_hangs(0.3, 3)\n"
        "ctypes.PyDLL(None).sleep(30)\n"  # a C call that keeps the GIL
    )
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=20.0
    )
    assert time.monotonic() - started < 15.0
    assert done.returncode == 3, done.stderr
    assert "teardown: DDS did not finish" not in done.stderr  # no Python thread ran


@pytest.mark.parametrize(("delay_s", "code"), [(0.0, 1), (1.0, 256), (1.0, -1)])
def test_the_exit_timer_refuses_what_it_cannot_do(delay_s, code) -> None:
    with pytest.raises(ValueError, match=r"must be > 0|must lie in \[0, 255\]"):
        exit_after(delay_s, code)


def test_a_hung_dds_teardown_ends_the_node_process_with_its_code() -> None:
    """A node process whose DDS teardown blocks (a reliable writer whose reader was killed) ends
    after the limit, with the code its nodes ended with and a line saying why."""
    script = (
        "import time\n"
        "from feed_twin.ros.runtime import exit_if_teardown_hangs\n"
        "exit_if_teardown_hangs(0.3, 3)\n"
        "time.sleep(30.0)\n"
    )
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=20.0
    )
    assert time.monotonic() - started < 15.0
    assert done.returncode == 3
    assert "teardown: DDS did not finish within 0.3 s; leaving" in done.stderr


def test_a_stopped_node_is_slow_not_gone_and_the_run_completes(config: Path) -> None:
    """SIGSTOP holds a node's heartbeats (as a host that does not schedule it for seconds
    would): its peers say once that it is slow, its process lives, and the run completes."""
    name = "stop_gcode"
    logs = config.parent / "bags" / f"{name}.logs"
    with reserve_domain_id() as domain:
        proc = start_sample_run(config, name, domain.domain_id)
        try:
            wait_for_progress(proc, logs / "sim.log", 1.0)
            pid = node_pids(config)["gcode"]
            os.kill(pid, signal.SIGSTOP)
            time.sleep(2.5)
            os.kill(pid, signal.SIGCONT)
            out, err = proc.communicate(timeout=180)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    assert proc.returncode == 0, err[-3000:]
    text = (logs / "sim.log").read_text(errors="replace")
    slow = re.search(
        r"node '/cnc/x/gcode' is slow: no progress for (\S+) s \(no heartbeat for [^)]*\), "
        r"its process lives",
        text,
    )
    assert slow is not None, text[-3000:]
    assert float(slow[1]) < 2.0  # said when the timeout passed, not at the end
    assert text.count("[cnc.x.sim]: node '/cnc/x/gcode' is slow") == 1  # said once
    assert "node '/cnc/x/gcode' moves again after " in text
    assert "is gone" not in text
    # the stopped node is in the run's slow line (on a loaded host its waiting peers can be
    # said slow beside it; the sim's own log above says the stopped one once)
    slow_line = next(ln for ln in err.splitlines() if "slow, not gone (the run went on):" in ln)
    assert "'/cnc/x/gcode' (" in slow_line, err
    # the run's report gives the whole stop (said when the node moved again)
    assert 2.5 <= last_json(out)["slow_nodes"]["/cnc/x/gcode"] < 5.0, out[-2000:]
    # the whole program, without a gap
    states = BagReader(config.parent / "bags" / name).columns("/cnc/x/state", ["header.stamp"])
    np.testing.assert_allclose(np.diff(states["header.stamp"]), 1e-3, atol=1e-9)
    assert states["header.stamp"].size > 7000, last_json(out)
