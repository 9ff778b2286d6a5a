"""Axis limits at short look-ahead: random programs planned in windows of `lookahead_segments`
moves (jerk profile), velocity, acceleration and jerk of every axis from differences of the
sampled positions (not from the planner's own numbers), against each axis's limits.

The programs are those of tests/test_gcode_planner.py (`tests/gcode_random.py`, seeds 0..n-1),
the config tests/fixtures/gcode/nc_test.yaml (its jerk filter T = A/J = 50 ms; `--filter-ms T`
sets every axis's j_max to a_max / T, e.g. 9 for the default axis's T). Prints each failing
seed with its worst ratios (peak / limit, 1 = at the limit) and, last, one JSON object of the
counts per look-ahead.

    .venv/bin/python benchmarks/lookahead_limits.py [--programs 100] [--moves 80] \
        [--lookahead 8 16 50] [--filter-ms 9]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from feed_twin.gcode import SampledTrajectory, load_nc_config, plan_program_stream

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from gcode_random import random_program, sampled_limit_ratios  # noqa: E402

CONFIG = load_nc_config(ROOT / "tests" / "fixtures" / "gcode" / "nc_test.yaml")


def main() -> None:
    parser = argparse.ArgumentParser(
        description="axis limits at short look-ahead, from the samples"
    )
    parser.add_argument("--programs", type=int, default=100)
    parser.add_argument("--moves", type=int, default=80)
    parser.add_argument("--lookahead", type=int, nargs="+", default=[8, 16, 50])
    parser.add_argument("--profile", choices=("jerk", "trapezoid"), default="jerk")
    parser.add_argument("--filter-ms", type=float, help="jerk filter time T = a_max / j_max")
    args = parser.parse_args()
    figures: dict[str, object] = {"programs": args.programs, "moves": args.moves}
    base = CONFIG
    if args.filter_ms is not None:
        # a hair above a_max / T, as config/axis_default.yaml rounds up: A/J within T's periods
        T = args.filter_ms * 1e-3
        axes = tuple(
            dataclasses.replace(a, j_max_m_s3=a.a_max_m_s2 / T * (1.0 + 1e-5)) for a in base.axes
        )
        base = dataclasses.replace(base, axes=axes)
        figures["filter_ms"] = args.filter_ms
    for lookahead in args.lookahead:
        config = dataclasses.replace(base, lookahead_segments=lookahead, profile=args.profile)
        failed: list[int] = []
        worst = [0.0, 0.0, 0.0]
        for seed in range(args.programs):
            program = random_program(np.random.default_rng(seed), args.moves)
            traj = SampledTrajectory.concatenate(plan_program_stream(program, config))
            ratios = sampled_limit_ratios(traj, config)
            if args.profile == "trapezoid":
                ratios = (ratios[0], ratios[1], 0.0)  # no jerk limit
            worst = [max(w, r) for w, r in zip(worst, ratios, strict=True)]
            if max(ratios) > 1.0:
                failed.append(seed)
                v, a, j = ratios
                print(f"lookahead {lookahead} seed {seed}: v {v:.4f} a {a:.4f} j {j:.4f}")
        print(f"lookahead {lookahead}: {len(failed)} of {args.programs} programs beyond a limit")
        figures[f"lookahead_{lookahead}"] = {
            "failed": len(failed),
            "seeds": failed,
            "worst_v_a_j": [round(w, 6) for w in worst],
        }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
