"""Two trees of feed_twin side by side: their own model_speed.py and nodes_speed.py, interleaved.

For each benchmark, `--pairs` times: the "before" tree's run, then this tree's run, each in a
fresh process whose `feed_twin` is that tree's (PYTHONPATH=<tree>, this tree's .venv: the
package is installed editable, and PYTHONPATH comes before the editable finder; checked for
each tree before anything runs). This venv must carry what both trees need. Interleaving
spreads the load of other jobs on a shared machine over both trees alike; the 1-minute load
average is logged before and after every run. Per-CPU-second figures (model_speed's `*_cpu`,
nodes_speed's CPU per exchange) are the ones that other jobs on the cores do not inflate.

    git worktree add /work/before <commit>
    .venv/bin/python benchmarks/before_after.py --before /work/before [--pairs 3]
        [--realtime-seconds 10] [--only tick|model|nodes|identity]

First `benchmarks/identity.py` (this tree's script) hashes both trees' results on the before
tree's machine file: which of its paths are bit for bit equal.

Figures compared (each: the before and after values of every pair, their medians and
after/before of the medians):
- tick (benchmarks/_tick_probe.py, this tree's, in both): a process's import, build and first
  run times, the best per-tick CPU time of the 1 s trapezoid (default and inlined kernel) and
  of model_speed's batch per set;
- model_speed (--skip-motulator): realtime_factor and _cpu, realtime_factor_inlined_cpu, the
  interleaved numba and C kernels' _cpu figures, batch_axis_seconds_per_cpu_second, first_run_s;
- nodes_speed (--probe-seconds 0, --realtime-seconds): lockstep_realtime_factor, the lockstep
  CPU per exchange of each node process, realtime p99 lateness and missed steps. A run that
  fails is kept with its error (and its lockstep figures when only the real-time part failed).

The last line is one JSON object: {"before", "identity", "runs": [...every run...], "summary"}.
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

MODEL_FIGURES = (
    "realtime_factor",
    "realtime_factor_cpu",
    "realtime_factor_inlined_cpu",
    "c_numba_realtime_factor_cpu",
    "c_realtime_factor_cpu",
    "batch_axis_seconds_per_cpu_second",
    "first_run_s",
)
TICK_FIGURES = (
    "import_s",
    "build_s",
    "first_run_s",
    "ns_per_tick",
    "ns_per_tick_inline",
    "batch_ns_per_set_tick",
)
NODES_FIGURES = (
    "lockstep_realtime_factor",
    "lockstep_cpu_us_per_exchange",
    "realtime_p99_lateness_ms",
    "missed_steps",
)


FIGURES = {"tick": TICK_FIGURES, "model": MODEL_FIGURES, "nodes": NODES_FIGURES}


def tree_env(tree: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    return env


def check_import(tree: Path) -> None:
    """The process started for `tree` imports that tree's feed_twin, not this venv's."""
    code = "import feed_twin; print(feed_twin.__file__)"
    done = subprocess.run(
        [sys.executable, "-c", code], env=tree_env(tree), cwd=tree, capture_output=True, text=True
    )
    got = Path(done.stdout.strip()).resolve()
    if got != (tree / "feed_twin" / "__init__.py").resolve():
        raise SystemExit(f"{tree}: a process there imports feed_twin from {got}, not the tree")


def run_one(bench: str, tree: Path, args: argparse.Namespace) -> dict[str, Any]:
    script = tree / "benchmarks" / f"{bench}_speed.py"
    if bench == "tick":  # this tree's probe, run in the other tree too
        script = ROOT / "benchmarks" / "_tick_probe.py"
    extra = ["--skip-motulator"] if bench == "model" else []
    if bench == "nodes":
        extra = ["--probe-seconds", "0", "--realtime-seconds", str(args.realtime_seconds)]
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(script), *extra],
        env=tree_env(tree),
        cwd=tree,
        capture_output=True,
        text=True,
        timeout=3600,
    )
    wall = time.perf_counter() - t0
    run: dict[str, Any] = {
        "bench": bench,
        "tree": str(tree),
        "load_1min_before": round(load_before, 2),
        "load_1min_after": round(os.getloadavg()[0], 2),
        "wall_s": round(wall, 1),
        "figures": {},
    }
    if done.returncode != 0:
        # kept, not fatal: at a load of 5-7 a real-time run can miss enough exchanges for the
        # drive to trip on its following error, in either tree
        lines = done.stderr.strip().splitlines() or [f"exit {done.returncode}"]
        run["failed"] = next((ln for ln in reversed(lines) if "error" in ln.lower()), lines[-1])
        run["figures"] = lockstep_line(done.stdout)
    else:
        run["figures"] = json.loads(done.stdout.strip().splitlines()[-1])
    return run


def identity(before: Path) -> dict[str, Any]:
    """benchmarks/identity.py's hashes of both trees, on the before tree's machine file (a newer
    file may carry sections an older loader refuses); which are equal."""
    hashes = {}
    for tree in (before, ROOT):
        command = [sys.executable, str(ROOT / "benchmarks" / "identity.py"), "--tree", str(tree)]
        command += ["--machine", str(before / "config" / "machine_default.yaml")]
        done = subprocess.run(
            command, env=tree_env(tree), cwd=tree, capture_output=True, text=True, timeout=3600
        )
        if done.returncode != 0:
            raise SystemExit(f"identity.py on {tree} failed:\n{done.stderr[-3000:]}")
        hashes[str(tree)] = json.loads(done.stdout.strip().splitlines()[-1])
    old, new = hashes[str(before)], hashes[str(ROOT)]
    return {
        "paths": len(old),
        "equal": sorted(k for k in old if new.get(k) == old[k]),
        "different": sorted(k for k in old if k in new and new[k] != old[k]),
        "only_before": sorted(set(old) - set(new)),
        "only_after": sorted(set(new) - set(old)),
    }


def lockstep_line(stdout: str) -> dict[str, Any]:
    """nodes_speed's lockstep figures from the line it prints before its real-time run (what is
    left of a run whose real-time part failed)."""
    match = re.search(
        r"^lockstep: .* realtime factor ([\d.]+); CPU per exchange \[us\] (\{.*\})$",
        stdout,
        re.MULTILINE,
    )
    if match is None:
        return {}
    return {
        "lockstep_realtime_factor": float(match[1]),
        "lockstep_cpu_us_per_exchange": ast.literal_eval(match[2]),
    }


def flat(figures: dict[str, Any], names: tuple[str, ...]) -> dict[str, float]:
    """The named figures, dicts (CPU per node) spread into name.key."""
    out: dict[str, float] = {}
    for name in names:
        value = figures.get(name)
        if isinstance(value, dict):
            out.update({f"{name}.{k}": float(v) for k, v in value.items()})
        elif value is not None:
            out[name] = float(value)
    return out


def summarise(runs: list[dict[str, Any]], before: Path) -> dict[str, Any]:
    summary: dict[str, Any] = {}
    for bench, names in FIGURES.items():
        rows = [r for r in runs if r["bench"] == bench]
        if not rows:
            continue
        sides: dict[str, dict[str, list[float]]] = {"before": {}, "after": {}}
        for row in rows:
            side = sides["before" if row["tree"] == str(before) else "after"]
            for key, value in flat(row["figures"], names).items():
                side.setdefault(key, []).append(value)
        figures = {}
        for key in sides["before"]:
            b, a = sides["before"][key], sides["after"].get(key, [])
            if not a:
                continue
            mb, ma = statistics.median(b), statistics.median(a)
            figures[key] = {
                "before": b,
                "after": a,
                "median_before": round(mb, 3),
                "median_after": round(ma, 3),
                "after_over_before": round(ma / mb, 3) if mb else None,
            }
        summary[bench] = {
            "figures": figures,
            "failed_before": sum("failed" in r for r in rows if r["tree"] == str(before)),
            "failed_after": sum("failed" in r for r in rows if r["tree"] != str(before)),
            # the 1-minute load average as each run started, per tree
            "load_at_start_before": [
                r["load_1min_before"] for r in rows if r["tree"] == str(before)
            ],
            "load_at_start_after": [
                r["load_1min_before"] for r in rows if r["tree"] != str(before)
            ],
        }
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--before", type=Path, help="the other tree (a worktree)")
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--realtime-seconds", type=float, default=10.0)
    parser.add_argument("--only", choices=(*FIGURES, "identity"))
    args = parser.parse_args()
    if args.before is None:  # `make bench` runs every benchmark without arguments
        print("before_after: no --before tree given, nothing to compare")
        print(json.dumps({"skipped": "no --before tree given"}))
        return
    before = args.before.resolve()
    if not (before / "feed_twin").is_dir():
        parser.error(f"--before {before}: not a feed_twin checkout (no feed_twin/ there)")
    for tree in (before, ROOT):
        check_import(tree)
    same = None
    if args.only in (None, "identity"):
        same = identity(before)
        print(
            f"identity: {len(same['equal'])} of {same['paths']} hashes equal; different: "
            f"{', '.join(same['different']) or 'none'}",
            flush=True,
        )
    benches = {None: tuple(FIGURES), "identity": ()}.get(args.only, (args.only,))
    runs = []
    for bench in benches:
        for pair in range(args.pairs):
            for tree in (before, ROOT):
                run = run_one(bench, tree, args)
                run["pair"] = pair
                runs.append(run)
                label = "before" if tree == before else "after"
                shown = flat(run["figures"], FIGURES[bench])
                print(
                    f"{bench} pair {pair} {label}: load {run['load_1min_before']:.2f}, "
                    f"{run['wall_s']:.0f} s, {run.get('failed') or json.dumps(shown)}",
                    flush=True,
                )
    summary = summarise(runs, before)
    print(json.dumps({"before": str(before), "identity": same, "runs": runs, "summary": summary}))


if __name__ == "__main__":
    main()
