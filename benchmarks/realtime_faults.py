"""Real-time node-set runs under the host's load: how many end in a drive fault, and how each
node process was scheduled. The last printed line is one JSON object.

`feed-twin run PROGRAM --realtime` (an axis file's node set: recorder, controller, sim and
G-code node in processes) `--runs` times; with `--before TREE` the other tree's run and this
tree's alternate (the first of each pair alternating too), so both see the same load from
other jobs on a shared host. Each run is a fresh process whose `feed_twin` is its tree's
(PYTHONPATH, as benchmarks/before_after.py). While a run lasts, every node process's scheduling
is read from /proc twice a second: its policy and real-time priority (every thread), nice and
CPU affinity; the run's JSON report gives the end (exit code, reason), the missed steps and
the lateness. A run that does not end within `--timeout` is a hang (it is killed).

The program (`--seconds`): benchmarks/nodes_speed.py's back-and-forth moves of 100 mm at
6 m/min: a starved setpoint stream shows as a following error of v * (time without
setpoints), so 20 ms without setpoints at 0.1 m/s reach the 2 mm limit of axis_default.yaml.

    git worktree add /tmp/before <commit>
    .venv/bin/python benchmarks/realtime_faults.py [--before /tmp/before] [--runs 5]
        [--seconds 20] [--config config/axis_default.yaml]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from before_after import check_import, tree_env
from nodes_speed import program

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_S = 0.5  # [s] between two readings of the node processes' scheduling
POLICIES = {0: "normal", 1: "fifo", 2: "rr", 3: "batch", 5: "idle"}  # sched(7) policy numbers


def descendants(pid: int) -> list[int]:
    """Every process below `pid`, read from /proc (children of each thread)."""
    found: list[int] = []
    try:
        threads = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return found
    for tid in threads:
        try:
            kids = Path(f"/proc/{pid}/task/{tid}/children").read_text().split()
        except OSError:
            continue
        for kid in map(int, kids):
            found += [kid, *descendants(kid)]
    return found


def _stat_fields(path: str) -> list[str]:
    """/proc/<pid>/stat's fields after the command name (field 3 on: proc(5))."""
    text = Path(path).read_text()
    return text[text.rindex(")") + 2 :].split()


def scheduling(pid: int) -> tuple[str, dict[str, Any]] | None:
    """(node module, its scheduling) of a node process; None for another process or one gone."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_text().split("\0")
        module = next((a for a in argv if a.startswith("feed_twin.ros.")), None)
        if module is None:
            return None
        fields = _stat_fields(f"/proc/{pid}/stat")
        threads = set()
        for tid in os.listdir(f"/proc/{pid}/task"):
            thread = _stat_fields(f"/proc/{pid}/task/{tid}/stat")
            # proc(5): rt_priority is field 40, policy 41; the list starts at field 3
            threads.add(f"{POLICIES.get(int(thread[38]), thread[38])} {thread[37]}")
        status = Path(f"/proc/{pid}/status").read_text().splitlines()
        cpus = next(ln.split()[1] for ln in status if ln.startswith("Cpus_allowed_list"))
    except (OSError, IndexError, StopIteration):
        return None
    role = module.rsplit(".", 1)[-1].removesuffix("_node")
    # nice is field 19
    return role, {"threads": sorted(threads), "nice": int(fields[16]), "cpus": cpus}


def one_run(tree: Path, prog: Path, config: Path, out: Path, name: str, timeout_s: float):
    """One real-time run of `tree`: its end, timing and the node processes' scheduling."""
    argv = [
        sys.executable, "-m", "feed_twin.cli", "run", str(prog), "--config", str(config),
        "--realtime", "--json", "--out", str(out), "--name", name,
    ]  # fmt: skip
    load = os.getloadavg()[0]
    started = time.monotonic()
    proc = subprocess.Popen(
        argv, cwd=tree, env=tree_env(tree), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    seen: dict[str, dict[str, Any]] = {}
    hang = False
    while proc.poll() is None:
        if time.monotonic() - started > timeout_s:
            hang = True
            proc.terminate()  # the runner stops its nodes (feed_twin.ros.launch)
            break
        for pid in descendants(proc.pid):
            found = scheduling(pid)
            if found is not None:
                seen[found[0]] = found[1]
        time.sleep(SAMPLE_S)
    stdout, _ = proc.communicate(timeout=60)
    lines = stdout.strip().splitlines()
    try:
        report = json.loads(lines[-1]) if lines else {}
    except json.JSONDecodeError:
        report = {}
    reason = report.get("reason") or ""
    return {
        "tree": str(tree),
        "exit_code": proc.returncode,
        "hang": hang,
        "fault": "drive fault" in reason,
        "reason": reason[-300:],
        "missed_steps": report.get("timing_missed_steps"),
        "lateness_p99_ms": report.get("timing_lateness_p99_ms"),
        "load_1min_at_start": round(load, 1),
        "wall_s": round(time.monotonic() - started, 1),
        "scheduling": seen,
    }


def tally(runs: list[dict[str, Any]], tree: Path) -> dict[str, Any]:
    mine = [r for r in runs if r["tree"] == str(tree)]
    return {
        "runs": len(mine),
        "faults": sum(r["fault"] for r in mine),
        "other_failures": sum(
            r["exit_code"] != 0 and not r["fault"] and not r["hang"] for r in mine
        ),
        "hangs": sum(r["hang"] for r in mine),
        "missed_steps": [r["missed_steps"] for r in mine],
        "load_1min_at_start": [r["load_1min_at_start"] for r in mine],
        # the last run's (the same in every run of a tree)
        "scheduling": mine[-1]["scheduling"] if mine else {},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="real-time runs under load: drive faults")
    parser.add_argument("--before", type=Path, default=None, help="the other tree (a worktree)")
    parser.add_argument("--runs", type=int, default=3, help="runs of each tree")
    parser.add_argument("--seconds", type=float, default=20.0, help="the program's length [s]")
    parser.add_argument(
        "--config", type=Path, default=None,
        help="axis file (default: each tree's own config/axis_default.yaml)",
    )  # fmt: skip
    parser.add_argument("--timeout", type=float, default=600.0, help="[s] a run's wall time")
    args = parser.parse_args()
    trees = [ROOT] if args.before is None else [args.before.resolve(), ROOT]
    for tree in trees:
        check_import(tree)
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="realtime_faults_") as tmp:
        directory = Path(tmp)
        prog = directory / "back_and_forth.ngc"
        prog.write_text(program(args.seconds))
        for i in range(args.runs):
            for tree in trees if i % 2 == 0 else trees[::-1]:
                label = "after" if tree == ROOT else "before"
                config = (args.config or tree / "config" / "axis_default.yaml").resolve()
                run = one_run(tree, prog, config, directory / label, f"r{i}", args.timeout)
                runs.append(run)
                print(
                    f"{label} run {i}: load {run['load_1min_at_start']}, exit {run['exit_code']}"
                    f", missed steps {run['missed_steps']}"
                    + (", HANG" if run["hang"] else "")
                    + (f", {run['reason'][-160:]}" if run["reason"] else ""),
                    flush=True,
                )
    summary = {("after" if t == ROOT else "before"): tally(runs, t) for t in trees}
    for label, figures in summary.items():
        print(
            f"{label}: {figures['faults']} drive faults, {figures['hangs']} hangs, "
            f"{figures['other_failures']} other failures in {figures['runs']} runs; "
            f"scheduling {json.dumps(figures['scheduling'])}"
        )
    print(json.dumps({"before": str(args.before), "summary": summary, "runs": runs}))


if __name__ == "__main__":
    main()
