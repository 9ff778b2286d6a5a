"""`feed-twin replay`: the shadow twin against a recorded bag, as fast as possible.

    feed-twin replay BAG --config MODEL [--map MAP] [--shadow SHADOW] [--axis NAME] --out DIR

MODEL is the model YAML of the discrepancy workflow (plant and controller sections); the
shadow settings come from its `shadow:` section or, when given, from the `shadow:` section of
SHADOW. Without --map, `<BAG stem>_map.yaml` next to the bag is used. Writes DIR/comparison
(the bag's topics plus the twin's), DIR/replay.rrd, DIR/report.json and DIR/report.md, and
prints the metrics, the fault counts and the health verdict.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="recorded rosbag2 directory (or its .mcap file)")
    parser.add_argument("--config", required=True, help="model YAML (plant, controller)")
    parser.add_argument("--map", help="column map YAML (default: <bag stem>_map.yaml)")
    parser.add_argument("--shadow", help="YAML with the shadow: section (default: --config)")
    parser.add_argument("--axis", default="x", help="axis name written into the twin's messages")
    parser.add_argument("--out", required=True, help="output directory")


def main(args: argparse.Namespace) -> int:
    from feed_twin.analysis.cli import _map_for
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.core.config import ConfigError
    from feed_twin.io.bag import BagError
    from feed_twin.io.measured import MeasuredDataError, load_column_map
    from feed_twin.io.progress import PassBar, wanted
    from feed_twin.shadow.config import load_shadow_config
    from feed_twin.shadow.replay import (
        replay,
        write_comparison_bag,
        write_report,
        write_rerun,
    )

    # the outputs take most of a replay's seconds (a 60 s bag: 0.2 s of twin, 4.9 s in all):
    # each step named on a terminal
    bar = PassBar(enabled=wanted(json_out=False))
    steps = ("replaying the bag", "writing the comparison bag", "writing the recording",
             "writing the report")  # fmt: skip

    def step(name: str) -> None:
        bar.begin(name, done=steps.index(name), planned=len(steps))

    def say(text: str) -> None:
        bar.say(f"[replay] {text}")

    bag = Path(args.bag)
    try:
        cmap = load_column_map(_map_for(bag, args.map))
        doc = ModelDoc.load(args.config)
        config = load_shadow_config(args.shadow or args.config)
        step(steps[0])
        t0 = time.perf_counter()
        result = replay(bag, doc, cmap, config)
        elapsed = time.perf_counter() - t0
    except (MeasuredDataError, ConfigError, BagError) as exc:
        bar.close()
        print(f"feed-twin replay: {exc}", file=sys.stderr)
        return 2
    s = result.samples
    duration = float(s.t_s[-1] - s.t_s[0]) if len(s) > 1 else 0.0
    rate = duration / elapsed
    say(f"{len(s)} samples ({duration:.3f} s) in {elapsed:.3f} s: {rate:.1f}x real time")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        step(steps[1])
        written = [write_comparison_bag(bag, result, out, args.axis)]
    except BagError as exc:
        bar.close()
        print(f"feed-twin replay: {exc}", file=sys.stderr)
        return 2
    step(steps[2])
    written.append(write_rerun(result, out / "replay.rrd"))
    step(steps[3])
    written += write_report(result, out, bag=str(bag), config=str(args.config))
    bar.close()
    m = result.metrics
    effort = "-" if m.effort_rel_err_pct is None else f"{m.effort_rel_err_pct:.4g}"
    say(
        f"FE deviation RMS {m.fe_dev_rms_m * 1e6:.4g} um (max {m.fe_dev_max_m * 1e6:.4g} um), "
        f"position rel. error {m.pos_rel_err_pct:.4g} %, effort rel. error "
        f"{effort} %"
    )
    for kind in ("command", "measured"):
        c = result.counts[kind]
        faults = ", ".join(f"{k} {v}" for k, v in c.items() if k not in ("received", "accepted"))
        say(f"{kind}: {c['received']} messages; {faults}")
    warnings = [v for v in result.verdicts if v.level != 0]
    if warnings:
        say(f"health: first {warnings[0].level_name} at t = {warnings[0].t_s:.3f} s")
    if result.verdicts:
        last = result.verdicts[-1]
        say(f"health: last {last.level_name} at t = {last.t_s:.3f} s: {last.message}")
    say("wrote " + ", ".join(str(p) for p in written))
    return 0
