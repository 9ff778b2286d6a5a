"""`feed-twin shadow`: the shadow twin beside the stand-in machine, two ROS 2 processes.

    feed-twin shadow --config MODEL [--duration 60] [--raise-friction-at T] [--friction-scale S]
                     [--jitter 2e-4] [--out DIR] [--live]

Starts `twin_node` and `standin_node` in a private ROS domain (feed_twin.ros.domain), waits
for the stand-in's program to end, and prints the twin's report: samples, message faults, the
lag of its output behind each measured sample, and the health verdict (the named effect when
the stand-in's friction was raised). DIR receives the column map and `shadow.rrd`; `--live`
streams the dashboard to a web viewer on 127.0.0.1 instead and prints its address.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

NAMESPACE = "/cnc/x"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="model YAML with shadow:")
    parser.add_argument("--duration", type=float, default=60.0, help="[s] of machine program")
    parser.add_argument("--raise-friction-at", type=float, help="[s] raise the truth friction")
    parser.add_argument("--friction-scale", type=float, default=1.35)
    parser.add_argument("--jitter", type=float, default=2e-4, help="[s] largest send delay")
    parser.add_argument("--out", type=Path, help="directory for the map and shadow.rrd")
    parser.add_argument("--live", action="store_true", help="serve a live Rerun web viewer")


def run_shadow(args: argparse.Namespace) -> tuple[int, dict | None, str]:
    """Run both nodes; (exit code, the twin's report, the twin's stderr)."""
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.ros.domain import private_graph_env, reserve_domain_id
    from feed_twin.shadow.standin import StandIn, write_map

    out = args.out or Path(tempfile.mkdtemp(prefix="feed_twin_shadow_"))
    out.mkdir(parents=True, exist_ok=True)
    from feed_twin.analysis.synthetic import Unmodelled

    standin = StandIn(
        ModelDoc.load(args.config), hidden={}, unmodelled=Unmodelled(), sample_period_s=1e-3,
        x0_m=0.0,
    )  # fmt: skip
    map_path = write_map(out / "standin_map.yaml", standin, NAMESPACE)
    viewer = None
    twin_cmd = [
        sys.executable, "-m", "feed_twin.ros.twin_node", "--config", str(args.config),
        "--map", str(map_path), "--rrd", str(out / "shadow.rrd"),
    ]  # fmt: skip
    if args.live:
        from feed_twin.io.dashboard import LiveViewer

        viewer = LiveViewer()
        twin_cmd += ["--rerun-url", viewer.grpc_url]
        print(f"[shadow] live dashboard: {viewer.web_url}", flush=True)
    standin_cmd = [
        sys.executable, "-m", "feed_twin.ros.standin_node", "--config", str(args.config),
        "--duration", str(args.duration), "--jitter", str(args.jitter),
        "--friction-scale", str(args.friction_scale),
    ]  # fmt: skip
    if args.raise_friction_at is not None:
        standin_cmd += ["--raise-friction-at", str(args.raise_friction_at)]
    procs: list[subprocess.Popen] = []
    logs = {name: out / f"{name}.log" for name in ("twin", "standin")}
    with reserve_domain_id() as domain, ExitStack() as files:
        env = {**os.environ, **private_graph_env(domain.domain_id)}
        try:
            for name, cmd in (("twin", twin_cmd), ("standin", standin_cmd)):
                log = files.enter_context(open(logs[name], "w"))  # noqa: SIM115
                procs.append(subprocess.Popen(cmd, env=env, stderr=log, stdout=log))
            # the stand-in's program sets the run's length; start-up (numba) and drain on top
            deadline = time.monotonic() + args.duration + 120.0
            while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
                time.sleep(0.2)
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait(timeout=10.0)
            if viewer is not None:
                viewer.stop()
    twin, standin_proc = procs
    twin_err = logs["twin"].read_text()
    standin_err = logs["standin"].read_text()
    report = None
    for line in twin_err.splitlines():
        if line.startswith("SHADOW "):
            report = json.loads(line[len("SHADOW ") :])
    code = twin.returncode or standin_proc.returncode
    return code, report, twin_err + standin_err


def main(args: argparse.Namespace) -> int:
    code, report, err = run_shadow(args)
    if report is None:
        print(f"feed-twin shadow: the twin node reported nothing (exit {code}):\n{err}",
              file=sys.stderr)  # fmt: skip
        return code or 1
    lag = report["lag_ms"]
    print(f"[shadow] {report['samples']} samples shadowed; lag p50 {lag['p50']:.3f} ms, "
          f"p99 {lag['p99']:.3f} ms, max {lag['max']:.3f} ms")  # fmt: skip
    for kind in ("command", "measured"):
        c = report["faults"][kind]
        print(f"[shadow] {kind}: " + ", ".join(f"{k} {v}" for k, v in c.items()))
    last = report["last"]
    if last is not None:
        print(f"[shadow] health {last['level']} at t = {last['t_s']:.3f} s: {last['message']}")
    for line in err.splitlines():
        if line.startswith("STANDIN"):
            print(f"[shadow] {line}")
    return code
