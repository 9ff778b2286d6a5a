"""Run one benchmark and keep its figures: benchmarks/results/NAME.json.

    .venv/bin/python tools/run_benchmark.py gcode_speed [ARGS...]

The benchmark's last printed line is its figures (one JSON object); they are saved with the
date, the host and the load average before and after the run, so a figure says when, where and
how shared the machine was. The previous result of the benchmark is replaced: the history is
git's. docs/benchmarks.md is then regenerated from every result (tools/benchmarks_page.py).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

USAGE = ".venv/bin/python tools/run_benchmark.py gcode_speed [ARGS...]"

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"


def run(name: str, args: list[str]) -> dict:
    script = ROOT / "benchmarks" / f"{name}.py"
    if not script.is_file():
        raise SystemExit(f"run_benchmark: no benchmark {script.relative_to(ROOT)}")
    load_before = os.getloadavg()[0]
    began = datetime.datetime.now(datetime.UTC)
    done = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, cwd=ROOT
    )
    if done.returncode != 0:
        raise SystemExit(f"run_benchmark: {name} failed:\n{done.stderr[-3000:]}")
    lines = [ln for ln in done.stdout.splitlines() if ln.strip()]
    try:
        figures = json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        raise SystemExit(f"run_benchmark: {name}: its last line is not one JSON object") from None
    return {
        "benchmark": name,
        "command": " ".join([".venv/bin/python", f"benchmarks/{name}.py", *args]),
        "date": began.strftime("%Y-%m-%d %H:%M UTC"),
        "host": f"{platform.node()} ({os.cpu_count()} cores, {platform.machine()})",
        "load_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "figures": figures,
    }


def main(argv: list[str]) -> int:
    if not argv:
        print(USAGE, file=sys.stderr)
        return 2
    result = run(argv[0], argv[1:])
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{argv[0]}.json").write_text(json.dumps(result, indent=2) + "\n")
    from benchmarks_page import write_page

    write_page()
    print(f"benchmarks/results/{argv[0]}.json; docs/benchmarks.md")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
