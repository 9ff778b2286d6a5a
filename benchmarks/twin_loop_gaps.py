"""Where the twin's loop beside LinuxCNC stops on a busy host: a per-turn timing trace.

Runs `feed-twin run PROGRAM --nc linuxcnc --shadow --json` (the X back-and-forth program of
benchmarks/linuxcnc_load.py, `--minutes` long) with `--load` busy processes per core
(linuxcnc_load's, started before and killed after) and FEED_TWIN_TURN_TRACE set, so that every
node process writes a trace of its loop's turns (feed_twin/nodeset/turn_trace.py). Prints, for
the twin node and the LinuxCNC bridge: turn gap p50/p99/max, the share of wall time on a CPU
and waiting on a run queue, the marked spans by kind (the twin's `process` = pairing, engine
and health; `publish`, `dashboard`, `verdict`, `tick`; the bridge's `rows`, `take`, `publish`,
`twin_output`; collections `gc<generation>`) and its largest gaps split into CPU, run-queue
wait, spans and the rest (off the CPU, not waiting for one: blocked or idle). Then the run's
own figures (bridge latency and its parts, twin output latency, slow nodes) and the host's
1-minute load average at the end (the host is shared).

    .venv/bin/python benchmarks/twin_loop_gaps.py [--minutes 1] [--load 2] [--top 5]
        [--config CONFIG]

Before/after of the bridge's and the twin's nice value (ros.linuxcnc_nice): a copy of
config/axis_default.yaml with `linuxcnc_nice: 0` under `ros:` as `--config`.

Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from linuxcnc_load import BUSY, CONFIG, one_run, write_program

from feed_twin.nodeset.turn_trace import TRACE_ENV, LoadedTrace

ROLES = ("twin", "linuxcnc", "recorder")


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--minutes", type=float, default=1.0, help="program length [min]")
    parser.add_argument("--load", type=int, default=2, help="busy processes per core")
    parser.add_argument("--top", type=int, default=5, help="largest gaps shown per node")
    parser.add_argument("--config", type=Path, default=CONFIG, help="axis config (an A/B of "
                        "its ros: settings, e.g. linuxcnc_nice: 0)")  # fmt: skip
    args = parser.parse_args()
    out = Path(tempfile.mkdtemp(prefix="feed_twin-loop-gaps-"))
    traces = out / "traces"
    traces.mkdir()
    program = write_program(out / "long.ngc", args.minutes)
    os.environ[TRACE_ENV] = str(traces)
    busy = [subprocess.Popen(BUSY) for _ in range(args.load * (os.cpu_count() or 1))]
    try:
        run = one_run(program, out, "gaps", args.minutes * 60.0 * 4 + 300.0, args.config)
    finally:
        for proc in busy:
            proc.kill()
            proc.wait()
    result: dict = {"minutes": args.minutes, "load": args.load, "config": str(args.config),
                    "run": run}  # fmt: skip
    for role in ROLES:
        found = sorted(traces.glob(f"{role}_*.npz"))
        if not found:
            print(f"{role}: no trace", flush=True)
            continue
        summary = LoadedTrace.load(found[0]).summary(top=args.top)
        result[role] = summary
        print(f"{role}: {json.dumps(summary)}", flush=True)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
