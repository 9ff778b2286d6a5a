"""CPU of the shadow twin node per 1 ms servo period, against how many periods it steps at once.

Beside LinuxCNC the twin node (feed_twin/ros/twin_node.py, `--batch-topic`) takes the bridge's
RecordBatches of AxisCommand and JointState messages and steps (pairs, advances its compiled
engine, checks health, packs its output, logs the dashboard) at most every STEP_EVERY_S. A
step has a fixed cost, so its CPU per period depends on how many periods one step covers. This
script builds the node as `feed-twin run --nc linuxcnc --shadow` does (config/axis_default.yaml,
the map LinuxCNC's joint gets, the .rrd dashboard unless `--no-dashboard`), feeds it
`--periods` periods of a synthetic LinuxCNC stream (a 10 mm, 0.5 Hz sine commanded, its
feedback one period later, as the bridge sends it) in batches of each `--steps` periods,
calling the node's own batch callback and step in process (no DDS: what the node does with a
batch, not the transport), and prints the process CPU per period.

    .venv/bin/python benchmarks/twin_step_cost.py [--periods 10000] [--steps 1,2,5,10,20]

Last line: one JSON object (`cpu_us_per_period` by periods per step).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.io.cdr import FlatCodec
from feed_twin.io.msg_types import AXIS_COMMAND
from feed_twin.nodeset.record_batch import RecordBatch
from feed_twin.shadow.bagstreams import encode_joint_state
from feed_twin.shadow.standin import write_map

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "axis_default.yaml"
NS = "/cnc/x"
PERIOD_NS = 1_000_000
AMPLITUDE_M = 0.01
OMEGA = 2.0 * math.pi * 0.5  # [rad/s]


def messages(periods: int) -> list[tuple[bytes, bytes | None]]:
    """(AxisCommand, JointState or None) CDR bytes per period, as the bridge encodes them."""
    command = FlatCodec(AXIS_COMMAND).fixed({"header.frame_id": "", "axis": "X"})
    out = []
    for k in range(periods):
        t = k * PERIOD_NS * 1e-9
        x = AMPLITUDE_M * math.sin(OMEGA * t)
        v = AMPLITUDE_M * OMEGA * math.cos(OMEGA * t)
        a = -AMPLITUDE_M * OMEGA**2 * math.sin(OMEGA * t)
        sec, nsec = divmod(k * PERIOD_NS, 1_000_000_000)
        cmd = command.encode((sec, nsec, x, v, a, 1))
        # row k's feedback is period k - 1's position
        x_prev = AMPLITUDE_M * math.sin(OMEGA * (t - PERIOD_NS * 1e-9))
        js = encode_joint_state((k - 1) * PERIOD_NS, ["x"], [x_prev], [], []) if k else None
        out.append((cmd, js))
    return out


def batches(stream: list[tuple[bytes, bytes | None]], per_step: int) -> list[bytes]:
    out = []
    for start in range(0, len(stream), per_step):
        batch = RecordBatch([f"{NS}/command", f"{NS}/joint_states"], 1)
        for cmd, js in stream[start : start + per_step]:
            batch.add(0, cmd, 0)
            if js is not None:
                batch.add(1, js, 0)
        data = batch.take()
        assert data is not None
        out.append(data)
    return out


def cost(stream, per_step: int, tmp: Path, context, dashboard: bool) -> float:
    """[us] process CPU per period with one step per `per_step` periods."""
    from feed_twin.ros import twin_node

    parser = argparse.ArgumentParser()
    twin_node.configure(parser)
    argv = ["--config", str(CONFIG), "--map", str(tmp / "map.yaml"), "--machine", "cnc",
            "--axis", "x", "--batch-topic", f"{NS}/linuxcnc/batch"]  # fmt: skip
    if dashboard:
        argv += ["--rrd", str(tmp / f"twin_{per_step}.rrd")]
    node = twin_node.build(parser.parse_args(argv), context)
    packed = batches(stream, per_step)
    try:
        started = time.process_time()
        for data in packed:
            node._on_batch(data)
            node._step()
        spent = time.process_time() - started
        if node.samples < len(stream) - per_step - 2:
            raise RuntimeError(f"the twin shadowed {node.samples} of {len(stream)} periods")
    finally:
        if node.dashboard is not None:
            node.dashboard.close()
        node.liveness.stop()
        node.destroy_node()
    return spent / len(stream) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--periods", type=int, default=10_000)
    parser.add_argument("--steps", default="1,2,5,10,20", help="periods per step, each timed")
    parser.add_argument("--no-dashboard", action="store_true", help="without the .rrd")
    args = parser.parse_args()
    from feed_twin.ros.dds import init_context

    context = init_context()
    stream = messages(args.periods)
    result: dict = {"periods": args.periods, "dashboard": not args.no_dashboard}
    per: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        twin = Twin.compile(ModelDoc.load(CONFIG))
        write_map(Path(tmp) / "map.yaml", twin, NS, 0.8, with_effort=False)
        for per_step in (int(s) for s in args.steps.split(",")):
            per[str(per_step)] = round(
                cost(stream, per_step, Path(tmp), context, not args.no_dashboard), 1
            )
            print(f"{per_step} periods per step: {per[str(per_step)]} us of CPU per period",
                  flush=True)  # fmt: skip
    context.try_shutdown()
    result["cpu_us_per_period"] = per
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
