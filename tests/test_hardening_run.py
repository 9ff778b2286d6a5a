"""Hardening of `feed-twin run` through the node set: the drive's fault reaction, foreign
publishers refused, runs that do not meet, no orphans, errors before any node starts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from nodes_support import (
    AXIS_CONFIG,
    SHORT_PROGRAM,
    Operator,
    last_json,
    node_env,
    run,
    start_run,
    wait_for_all,
)
from run_report_support import assert_report

from feed_twin.io.bag import BagReader
from feed_twin.ros.domain import reserve_domain_id

pytestmark = [pytest.mark.ros]

FAR_PROGRAM = "G21 G90 G54\nG0 X-200\nM30\n"  # a 200 mm rapid: the axis's largest following error

INTRUDER = """
import struct, sys, time, rclpy
from rclpy.serialization import deserialize_message
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, AxisState
from feed_twin.ros.dds import DATA_QOS
rclpy.init()
node = rclpy.create_node("intruder")
command = node.create_publisher(AxisCommand, "/cnc/x/command", DATA_QOS)
feedback = node.create_publisher(AxisFeedback, "/cnc/x/feedback", DATA_QOS)
state = node.create_publisher(AxisState, "/cnc/x/state", DATA_QOS)
# The run's own signed commands, to send again altered and replayed. This reader hears the
# intruder's own commands too: taking one message a pass, it had 5000 of its own queued ahead
# of the run's first and heard the run 2-3 s late, and it went on to replay and alter its own
# altered copies (bad tags, not replays). So each pass takes every message and keeps the
# newest signed one whose sequence number (the signature's first 16 hex digits) is new.
heard = node.create_subscription(
    AxisCommand, "/cnc/x/command", lambda _: None, DATA_QOS, raw=True
)
end = time.monotonic() + float(sys.argv[1])
k = 0
newest = ""
print("publishing", flush=True)
while time.monotonic() < end:
    signed = None
    with heard.handle:
        while (taken := heard.handle.take_message(AxisCommand, True)) is not None:
            seq = deserialize_message(taken[0], AxisCommand).header.frame_id[:16]
            if seq > newest:
                newest, signed = seq, bytearray(taken[0])
    # setpoints 100 mm away from the program's, alternating: a lethal stream if taken
    command.publish(AxisCommand(axis="X", position=0.3 + 0.2 * (k % 2), line=99))
    feedback.publish(AxisFeedback(axis="X", scale_position=0.77, i_q=25.0))
    state.publish(AxisState(axis="X", table_position=0.77, following_error=0.5))
    if signed is not None:
        command.publish(bytes(signed))  # replayed as it was
        struct.pack_into("<d", signed, len(signed) - 28, 0.0015)  # its position 1.5 mm
        command.publish(bytes(signed))  # altered, the signature kept
    k += 1
    time.sleep(0.002)
"""


def config_with(tmp_path: Path, edit) -> Path:
    data = yaml.safe_load(AXIS_CONFIG.read_text())
    edit(data)
    path = tmp_path / "axis.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_following_error_limit_stops_the_run_naming_limit_time_and_line(tmp_path):
    tight = config_with(
        tmp_path, lambda d: d["controller"]["position"].update(following_error_limit_m=2e-4)
    )
    program = tmp_path / "far.ngc"
    program.write_text(FAR_PROGRAM)
    with reserve_domain_id() as domain:
        code, out, err = run(
            [str(program), "--config", str(tight), "--out", str(tmp_path / "bags"),
             "--name", "far", "--json"],
            domain.domain_id,
        )  # fmt: skip
    record = last_json(out)
    assert code == 1 and record["exit_code"] == 1, err
    reason = record["reason"]
    # the node and its namespace, then its own words: no log prefix, no run_state word
    assert reason.startswith("sim node (cnc/x) exited with code 1: drive fault 1 at t = 0.0"), (
        reason
    )
    assert "exceeds the limit 0.200 mm (controller.position.following_error_limit_m)" in reason
    assert reason.endswith("(program line 2: G0 X-200)")
    feedback = BagReader(record["bag"]).columns(
        "/cnc/x/feedback", ["following_error", "status_word", "fault_code"]
    )
    # The last exchange reports the fault: FAULT bit set, power stage off, fault code 1.
    assert feedback["fault_code"][-1] == 1 and int(feedback["status_word"][-1]) & 8
    assert not int(feedback["status_word"][-1]) & 4
    assert abs(feedback["following_error"][-1]) > 2e-4
    assert np.all(feedback["fault_code"][:-1] == 0)


# The run holds at M0 until the test presses start, which it does once the nodes' logs show
# that the recorder has refused and named the intruder on every topic and the controller its
# feedback, and that the run's own commands came back replayed and altered. Discovery of a
# participant that was up before the run (the intruder) took 0-3 s here, and a lockstep run
# goes faster than real time: the 6 s dwell this test had (simulated) lasted 1.3 s of wall time
# on a quiet host, and the run sometimes ended before the sim's process had met the intruder.
PAUSED_PROGRAM = SHORT_PROGRAM.replace("G1 X10", "M0\nG1 X10")
FOREIGN_TOPICS = ("/cnc/x/command", "/cnc/x/feedback", "/cnc/x/state")
REFUSED = r"refused \d+ foreign message\(s\) on "  # feed_twin.ros.runtime.refuse_foreign
FOREIGN_SEEN = [
    *(rf"\[cnc\.x\.recorder\]: {REFUSED}{t} " for t in FOREIGN_TOPICS),
    *(rf"\[cnc\.x\.recorder\]: foreign publisher on {t}: node '/intruder'" for t in FOREIGN_TOPICS),
    rf"\[cnc\.x\.controller\]: {REFUSED}/cnc/x/feedback ",
    *(rf"{REFUSED}/cnc/x/command \({why}\)" for why in ("unsigned", "replayed", "bad tag")),
]


def test_foreign_publishers_on_every_topic_are_dropped_counted_and_named(tmp_path):
    """Unsigned commands, feedback and states, and the run's own commands replayed and altered
    (#29): none is recorded, none moves the axis or ends the run, and the run names the
    intruder in its own output and JSON."""
    program = tmp_path / "move.ngc"
    program.write_text(PAUSED_PROGRAM)
    with reserve_domain_id() as domain:
        intruder = subprocess.Popen(
            [sys.executable, "-c", INTRUDER, "300"],
            env=node_env(domain.domain_id),
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        try:
            assert intruder.stdout is not None
            assert intruder.stdout.readline().strip() == "publishing"
            with Operator(domain.domain_id) as operator:
                proc = start_run(
                    [str(program), "--out", str(tmp_path / "bags"), "--name", "mixed", "--json"],
                    domain.domain_id,
                )
                try:
                    wait_for_all(tmp_path / "bags" / "mixed.logs", FOREIGN_SEEN, proc, 90.0)
                    assert operator.press("/cnc/x/gcode/start") == "resumed"
                    out, err = proc.communicate(timeout=240)
                finally:
                    if proc.poll() is None:
                        proc.kill()
                        proc.communicate(timeout=10)
        finally:
            intruder.kill()
            intruder.wait(timeout=10)
    record = last_json(out)
    assert proc.returncode == 0, err
    # The program moves 10 mm at 3 m/min: following error of a fraction of a millimetre, not
    # the 100 mm the intruder's setpoints would give, nor its 0.5 m state.
    assert record["following_error_max_m"] < 5e-4
    foreign = record["foreign_messages"]
    for topic in FOREIGN_TOPICS:
        assert foreign[topic]["messages"] > 0, foreign
        assert any("node '/intruder'" in p for p in foreign[topic]["publishers"]), foreign
        assert f"{topic}: {foreign[topic]['messages']} dropped, from node '/intruder'" in out
    reasons = foreign["/cnc/x/command"]["reasons"]
    assert reasons["unsigned"] > 0 and reasons["replayed"] > 0 and reasons["bad tag"] > 0
    bag = BagReader(record["bag"])
    assert np.all(bag.columns("/cnc/x/command", ["line"])["line"] != 99)
    states = bag.columns("/cnc/x/state", ["header.stamp", "table_position"])
    assert np.all(np.diff(states["header.stamp"]) > 0)  # one sample per exchange, the sim's
    assert np.max(np.abs(states["table_position"])) < 0.5
    assert np.all(bag.columns("/cnc/x/feedback", ["scale_position"])["scale_position"] < 0.5)
    log = (Path(record["logs"]) / "controller.log").read_text()
    assert "foreign publisher on /cnc/x/command: node '/intruder'" in log
    health = BagReader(record["bag"]).columns("/cnc/x/health", ["message"])["message"]
    assert any("foreign publisher" in m for m in health)


def test_two_runs_on_one_host_do_not_meet(tmp_path):
    program = tmp_path / "move.ngc"
    program.write_text(SHORT_PROGRAM)
    env = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "feed_twin.cli",
                "run",
                str(program),
                "--out",
                str(tmp_path / "bags"),
                "--name",
                f"run{i}",
                "--json",
            ],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        for i in range(2)
    ]
    results = [p.communicate(timeout=300) for p in procs]
    records = [last_json(out) for out, _ in results]
    for p, (_, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
    # Each bag holds its own run only: one command stream, the same figures.
    for record in records:
        commands = BagReader(record["bag"]).columns("/cnc/x/command", ["header.stamp"])
        stamps = commands["header.stamp"]
        assert np.all(np.diff(stamps) > 0)
    assert records[0]["following_error_max_m"] == pytest.approx(
        records[1]["following_error_max_m"], rel=1e-9
    )


def test_no_node_outlives_a_killed_runner(tmp_path):
    program = tmp_path / "move.ngc"
    program.write_text(SHORT_PROGRAM)
    with reserve_domain_id() as domain:
        runner = start_run(
            [str(program), "--out", str(tmp_path / "bags"), "--realtime"], domain.domain_id
        )
        deadline = time.monotonic() + 60
        children: list[int] = []
        while time.monotonic() < deadline and len(children) < 3:
            time.sleep(0.2)
            children = _children(runner.pid)
        assert len(children) >= 3
        runner.send_signal(signal.SIGKILL)
        runner.communicate(timeout=10)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and any(_alive(pid) for pid in children):
            time.sleep(0.1)
    assert not any(_alive(pid) for pid in children)


def _children(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def test_config_errors_end_the_run_before_any_node_starts(tmp_path):
    program = tmp_path / "move.ngc"
    program.write_text(SHORT_PROGRAM)
    fast_rapid = config_with(tmp_path, lambda d: d["nc"]["axes"][0].update(rapid_m_s=0.5))
    started = time.monotonic()
    with reserve_domain_id() as domain:
        code, out, err = run(
            [str(program), "--config", str(fast_rapid), "--out", str(tmp_path / "bags"),
             "--json"],
            domain.domain_id,
        )  # fmt: skip
    assert code == 1 and time.monotonic() - started < 30.0
    assert err.strip().count("\n") == 0
    assert "nc.axes[X].rapid_m_s = 0.5: the motor needs 401 V" in err
    record = assert_report(out)  # the report of every mode, with nothing written
    assert record["exit_code"] == 1 and record["bag"] is None
    assert record["reason"] == err.strip().removeprefix("feed-twin run: ")
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())
