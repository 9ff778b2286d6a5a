"""Foreign publishers against a run (issue 29): the last line is one JSON object.

Each case runs `feed-twin run` (the single-axis node set) while an intruder process in the
run's ROS domain publishes on one of its topics:
- fabricated AxisState, AxisFeedback, AxisCommand and DriveCommand messages, unsigned and with
  a copied signature (the last one it heard on the topic);
- the run's own messages, heard on the topic and sent again altered (the position 1.5 mm off,
  its signature kept) or replayed unaltered.
The run is deterministic, so each attacked run is compared with a clean one, message by
message: "recorded" counts the messages of the attacked bag that the clean bag does not have
(the intruder's), "moved" is the largest difference of the table position [m]. A case passes
with recorded 0, moved 0, exit code 0 and the intruder named in `foreign_messages`. The cost
of the protection is measured per message: signing at the publisher and checking at each
receiver (feed_twin.nodeset.auth), for each message type of an exchange.

    .venv/bin/python benchmarks/security.py [--only NAME_PART] [--repeats N]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "feed_twin.cli"]
PROGRAM = "G21 G90 G54\nG1 X30 F1200\nG1 X0\nM30\n"  # 3 s of motion
RUN_TIMEOUT_S = 300.0
COMPARED = {  # topic -> fields compared between the clean and the attacked bag
    "/cnc/x/state": ["header.stamp", "table_position", "following_error", "i_q"],
    "/cnc/x/feedback": ["header.stamp", "scale_position", "i_q"],
    "/cnc/x/command": ["header.stamp", "position", "line"],
    "/cnc/x/drive_command": ["header.stamp", "position", "torque", "i_q"],
}

INTRUDER = r"""
import collections, sys, time, struct, rclpy
from rclpy.serialization import serialize_message
from rclpy.qos import QoSProfile
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, AxisState, DriveCommand
from feed_twin.ros.dds import DATA_QOS
kind, topic, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
types = {"state": AxisState, "feedback": AxisFeedback, "command": AxisCommand,
         "drive_command": DriveCommand}
msg_type = types[topic.rsplit("/", 1)[1]]
rclpy.init()
node = rclpy.create_node("intruder")
pub = node.create_publisher(msg_type, topic, DATA_QOS)
heard = []
# The subscription hears this process's own publications too: each message sent is counted and
# dropped once when it comes back, so "altered" never alters its own copies and "replayed" never
# replays them (the run's messages are signed per message, so no run message equals a copy).
echoes = collections.Counter()


def hear(data):
    if echoes[data] > 0:
        echoes[data] -= 1
    else:
        heard.append(data)


def send(m):
    data = m if isinstance(m, bytes) else serialize_message(m)
    echoes[data] += 1
    pub.publish(data)


node.create_subscription(msg_type, topic, hear, DATA_QOS, raw=True)

def fabricated(k):
    m = msg_type(axis="X")
    if msg_type is AxisState:
        m.table_position, m.following_error, m.position_setpoint = 0.77, 0.5, 0.27
    elif msg_type is AxisFeedback:
        m.scale_position, m.encoder_angle, m.i_q = 0.77, 400.0, 25.0
    elif msg_type is AxisCommand:
        m.position, m.line = 0.3 + 0.2 * (k % 2), 99
    else:
        m.mode, m.enable, m.i_q, m.torque = 10, True, 30.0, 50.0
    m.header.stamp.sec, m.header.stamp.nanosec = 0, 1_000_000 * (k % 1000)
    return m

def altered(data):
    # the first float64 after the header and the axis label: a position in every type here
    b = bytearray(data)
    n = struct.unpack_from("<I", b, 12)[0]
    at = 16 + n
    at += -at % 4
    at += 4 + struct.unpack_from("<I", b, at)[0]
    at += -(at - 4) % 8
    if msg_type is DriveCommand:
        at += 8  # mode, enable, then the position
    (x,) = struct.unpack_from("<d", b, at)
    struct.pack_into("<d", b, at, x + 1.5e-3)
    return bytes(b)

print("up", flush=True)
end, k, sent = time.monotonic() + seconds, 0, 0
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.0)
    if kind == "unsigned":
        send(fabricated(k)); sent += 1
    elif kind == "copied_signature" and heard:
        m = fabricated(k)
        b = bytearray(heard[-1])
        m.header.frame_id = bytes(b[16:16 + struct.unpack_from("<I", b, 12)[0] - 1]).decode()
        send(m); sent += 1
    elif kind == "altered" and heard:
        send(altered(heard.pop(0))); sent += 1
    elif kind == "replayed" and len(heard) > 50:
        send(heard.pop(0)); sent += 1
    k += 1
    time.sleep(0.001)
print(f"sent {sent}", flush=True)
"""

CASES = [
    (kind, topic)
    for topic in ("/cnc/x/state", "/cnc/x/feedback", "/cnc/x/command", "/cnc/x/drive_command")
    for kind in ("unsigned", "copied_signature", "altered", "replayed")
]


def run(work: Path, name: str, env: dict) -> tuple[int | None, dict, str]:
    program = work / "move.ngc"
    program.write_text(PROGRAM)
    args = [*CLI, "run", str(program), "--out", str(work / "bags"), "--name", name, "--json"]
    try:
        done = subprocess.run(
            args, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, cwd=ROOT, env=env
        )
    except subprocess.TimeoutExpired:
        return None, {}, "hung"
    try:
        record = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        record = {}
    return done.returncode, record, done.stderr


def columns(bag: str) -> dict[str, dict[str, np.ndarray]]:
    from feed_twin.io.bag import BagReader

    reader = BagReader(bag)
    return {topic: reader.columns(topic, fields) for topic, fields in COMPARED.items()}


def compare(clean: dict, attacked: dict) -> tuple[int, float]:
    """(messages of the attacked bag that the clean one lacks, largest table difference [m])."""
    extra = 0
    for topic, fields in COMPARED.items():
        a, c = attacked[topic], clean[topic]
        rows_a = {tuple(a[f][k] for f in fields) for k in range(len(a[fields[0]]))}
        rows_c = {tuple(c[f][k] for f in fields) for k in range(len(c[fields[0]]))}
        extra += len(rows_a - rows_c) + max(len(a[fields[0]]) - len(c[fields[0]]), 0)
    xa = attacked["/cnc/x/state"]["table_position"]
    xc = clean["/cnc/x/state"]["table_position"]
    n = min(len(xa), len(xc))
    moved = float(np.max(np.abs(xa[:n] - xc[:n]))) if n else float("nan")
    if len(xa) != len(xc):
        moved = max(moved, float("inf"))
    return extra, moved


def attack(work: Path, kind: str, topic: str, clean: dict, domain: int) -> dict:
    from feed_twin.ros.domain import private_graph_env

    env = {**os.environ, **private_graph_env(domain)}
    intruder = subprocess.Popen(
        [sys.executable, "-c", INTRUDER, kind, topic, "120"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, cwd=ROOT, env=env,
    )  # fmt: skip
    assert intruder.stdout is not None, "started with stdout=PIPE"
    try:
        intruder.stdout.readline()  # "up"
        name = f"{kind}_{topic.rsplit('/', 1)[1]}"
        rc, record, err = run(work, name, env)  # ROS_DOMAIN_ID: the intruder's
    finally:
        intruder.terminate()
        intruder.wait(timeout=30)
    foreign = record.get("foreign_messages") or {}
    entry = foreign.get(topic) or {}
    named = any("intruder" in p for p in entry.get("publishers", ()))
    result = {"case": f"{kind} {topic}", "exit_code": rc, "dropped": entry.get("messages", 0)}
    if record.get("bag"):
        extra, moved = compare(clean, columns(record["bag"]))
        result.update(recorded=extra, moved_m=moved)
    else:
        result.update(recorded=None, moved_m=None, error=err.strip()[-200:])
    result["named"] = named
    result["passed"] = (
        rc == 0 and result.get("recorded") == 0 and result.get("moved_m") == 0.0 and named
    )
    return result


def _cost(type_name: str, repeats: int) -> dict[str, float]:
    from feed_twin.io.cdr import FlatCodec
    from feed_twin.nodeset.auth import Signer, Verifier, new_key

    layout = FlatCodec(type_name).fixed({"axis": "X"})
    values = tuple(range(len(layout.numbers)))
    data = layout.encode(values)
    key = new_key()
    signer, verifier = Signer(key, "/t"), Verifier(key, "/t")
    sign_s = timeit.timeit(lambda: signer.sign(data), number=repeats) / repeats
    signed = iter([signer.sign(data) for _ in range(repeats)])
    check_s = timeit.timeit(lambda: verifier.verify(next(signed)), number=repeats) / repeats
    encode_s = timeit.timeit(lambda: layout.encode(values), number=repeats) / repeats
    return {
        "sign_us": sign_s * 1e6, "check_us": check_s * 1e6, "encode_us": encode_s * 1e6,
        "bytes": len(data),
    }  # fmt: skip


def message_costs(repeats: int) -> dict[str, dict[str, float]]:
    """Sign and check [us] per message of each type a run's exchange carries."""
    from feed_twin.io import msg_types

    types = (msg_types.AXIS_COMMAND, msg_types.DRIVE_COMMAND, msg_types.AXIS_FEEDBACK,
             msg_types.AXIS_STATE)  # fmt: skip
    return {t.rsplit("/", 1)[1]: _cost(t, repeats) for t in types}


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--only", default="", help="the cases whose name contains this")
    parser.add_argument("--repeats", type=int, default=20000, help="for the per-message cost")
    parser.add_argument("--costs-only", action="store_true", help="no runs, the cost only")
    args = parser.parse_args()
    from feed_twin.ros.domain import private_graph_env, reserve_domain_id

    costs = message_costs(args.repeats)
    for name, c in costs.items():
        print(f"{name:<14} sign {c['sign_us']:6.2f} us  check {c['check_us']:6.2f} us  "
              f"(encoding alone {c['encode_us']:5.2f} us, {c['bytes']} bytes)")  # fmt: skip
    results = []
    if args.costs_only:
        print(json.dumps({"cost_per_message_us": costs}))
        return 0
    with tempfile.TemporaryDirectory(prefix="feed_twin_security_") as tmp, reserve_domain_id() as d:
        work = Path(tmp)
        env = {**os.environ, **private_graph_env(d.domain_id)}
        started = time.monotonic()
        rc, record, err = run(work, "clean", env)
        if rc != 0 or not record.get("bag"):
            print(f"the clean run failed: exit {rc}: {err.strip()[-300:]}")
            return 1
        clean = columns(record["bag"])
        print(f"clean run: {time.monotonic() - started:.1f} s")
        for kind, topic in CASES:
            if args.only not in f"{kind} {topic}":
                continue
            started = time.monotonic()
            result = attack(work, kind, topic, clean, d.domain_id)
            result["seconds"] = time.monotonic() - started
            mark = "pass" if result["passed"] else "FAIL"
            print(
                f"{mark} {result['case']:<36} exit {result['exit_code']}, dropped "
                f"{result['dropped']}, recorded {result['recorded']}, moved "
                f"{result['moved_m']}, named {result['named']} ({result['seconds']:.0f} s)"
            )
            results.append(result)
    per_exchange = sum(c["sign_us"] + 2 * c["check_us"] for c in costs.values())
    summary = {
        "cases": len(results),
        "passed": sum(r["passed"] for r in results),
        "failed": [r["case"] for r in results if not r["passed"]],
        "recorded_max": max((r["recorded"] or 0) for r in results) if results else None,
        "moved_max_m": max((r["moved_m"] or 0.0) for r in results) if results else None,
        "cost_per_message_us": costs,
        # each of the four messages signed once and checked by its receiver and the recorder
        "cost_per_exchange_us": per_exchange,
    }
    print(json.dumps(summary))
    return 0 if summary["passed"] == summary["cases"] else 1


if __name__ == "__main__":
    sys.exit(main())
