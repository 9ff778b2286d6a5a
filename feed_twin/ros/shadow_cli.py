"""`feed-twin shadow`: the shadow twin beside the stand-in machine on its built-in program.

    feed-twin shadow --config MODEL [--duration 60] [--raise-friction-at T] [--friction-scale S]
                     [--jitter 2e-4] [--out DIR] [--live]

Starts `twin_node` and `standin_node` (built-in program, real time) in a private ROS domain
(feed_twin.ros.domain) through the launcher of `feed-twin run` (feed_twin.ros.launch: a
node that dies is noticed by the other within a second, SIGINT/SIGTERM stop both cleanly),
waits for the stand-in's program to end, and prints the twin's report: samples, message faults,
the lag of its output behind each measured sample, and the health verdict (the named effect
when the stand-in's friction was raised). DIR receives the column map, the node logs and
`shadow.rrd`; `--live` also streams the dashboard to a web viewer on 127.0.0.1 and prints its
address. The stand-in's truth comes from the config's `shadow.standin` section; `--jitter` and
`--raise-friction-at` override it. `feed-twin run PROGRAM --shadow` is the same pair of nodes
following a G-code program, with the recorder.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

NAMESPACE = "/cnc/x"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="model YAML with shadow:")
    parser.add_argument("--duration", type=float, default=60.0, help="[s] of machine program")
    parser.add_argument("--raise-friction-at", type=float, help="[s] raise the truth friction")
    parser.add_argument(
        "--friction-scale", type=float, default=1.35,
        help="factor on the truth friction from --raise-friction-at on (default 1.35)",
    )  # fmt: skip
    parser.add_argument(
        "--jitter", type=float, help="[s] largest send delay (default: shadow.standin.jitter_s)"
    )
    parser.add_argument("--out", type=Path, help="directory for the map and shadow.rrd")
    parser.add_argument("--live", action="store_true", help="serve a live Rerun web viewer")


def shadow_plan(args: argparse.Namespace, map_path: Path, rrd: Path, live_url: str | None):
    """The twin and the stand-in on its built-in program, each in its own process; the stand-in
    is the clock (feed_twin.launch.plan)."""
    from feed_twin.launch.plan import RunPlan

    twin = ["--config", str(args.config), "--map", str(map_path), "--rrd", str(rrd),
            "--peers", "standin"]  # fmt: skip
    if live_url is not None:
        twin += ["--rerun-url", live_url]
    standin = ["--config", str(args.config), "--duration", str(args.duration),
               "--friction-scale", str(args.friction_scale), "--peers", "twin"]  # fmt: skip
    if args.jitter is not None:
        standin += ["--jitter", str(args.jitter)]
    if args.raise_friction_at is not None:
        standin += ["--raise-friction-at", str(args.raise_friction_at)]
    return RunPlan.of({"twin": [("twin", twin)], "standin": [("standin", standin)]},
                      clock="standin")  # fmt: skip


def run_shadow(args: argparse.Namespace) -> tuple[int, dict | None, str]:
    """Run both nodes; (exit code, the twin's report, the twin's and the stand-in's logs)."""
    from feed_twin.analysis.twin import ModelDoc, Twin
    from feed_twin.ros.domain import private_graph_env, reserve_domain_id
    from feed_twin.ros.executors import run_processes
    from feed_twin.ros.launch import log_record
    from feed_twin.shadow.standin import write_map

    out = args.out or Path(tempfile.mkdtemp(prefix="feed_twin_shadow_"))
    out.mkdir(parents=True, exist_ok=True)
    map_path = write_map(
        out / "standin_map.yaml", Twin.compile(ModelDoc.load(args.config)), NAMESPACE
    )
    viewer = None
    try:
        if args.live:
            from feed_twin.io.live import LiveViewer

            viewer = LiveViewer()
            print(f"[shadow] live dashboard: {viewer.web_url}", flush=True)
        plan = shadow_plan(args, map_path, out / "shadow.rrd", viewer and viewer.grpc_url)
        with reserve_domain_id() as domain:
            env = {**os.environ, **private_graph_env(domain.domain_id)}
            # the stand-in's program sets the run's length; start-up (numba) and drain on top
            result = run_processes(
                plan, out, env, quiet=False, total_s=args.duration,
                deadline_s=args.duration + 120.0,
            )  # fmt: skip
    finally:
        if viewer is not None:
            viewer.stop()
    logs = "".join(result.logs[r].read_text(errors="replace") for r in ("twin", "standin"))
    if result.reason:
        logs += f"\n{result.reason}"
    return result.code, log_record(result.logs["twin"], "SHADOW"), logs


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
