"""Wall time of `diagnose` on a 20 s, 1 kHz record (median of three runs).

The record is a synthetic EMPS run (analysis.synthetic) of the test program played three times
and cut to its first 20 s, with two hidden effects (Coulomb friction and a constant force), so
the workflow goes through two rounds of add-and-fit, the re-examination and the joint re-fit.
The search's cost (parameter sets simulated, from report.json's `search`) is printed beside it.
A warm-up run compiles every kernel structure first (numba's on-disk cache: its time, reported
as `warmup_s`, is a compile only on the first run after a change of the kernels' source, a cache
load otherwise). Target: median <= 10 s of wall time.

The machine is shared: wall time follows the load (a run that gets a third of a core takes three
times as long), so each run's CPU time of this process (`cpu_s`, all its threads: the batches of
the Jacobians run on every core, so on an idle machine the wall time lies between cpu_s / cores
and cpu_s) and the 1-minute load average before and after the runs are reported beside it.
The runs use one OpenBLAS thread, as `feed-twin diagnose` does (feed_twin.analysis.cli): with
OpenBLAS's default of one thread per core its threads spin against the engine's and the other
processes' and the same run took 0.9 to 10.5 s at load 6 (`FEED_TWIN_BENCH_BLAS_THREADS=0`).
Last printed line: one JSON object of the figures.

    .venv/bin/python benchmarks/diagnose_record_speed.py
"""

from __future__ import annotations

import json
import os
import statistics
import tempfile
import time
from pathlib import Path

# what `feed-twin diagnose` runs with (feed_twin.analysis.cli): one OpenBLAS thread, set before
# numpy loads; FEED_TWIN_BENCH_BLAS_THREADS=0 leaves OpenBLAS its default (one per core)
_blas = os.environ.get("FEED_TWIN_BENCH_BLAS_THREADS", "1")
if _blas != "0":
    os.environ["OPENBLAS_NUM_THREADS"] = _blas

from feed_twin.analysis.diagnose import diagnose  # noqa: E402
from feed_twin.analysis.synthetic import PROGRAM, generate, write_csv  # noqa: E402
from feed_twin.analysis.twin import ModelDoc  # noqa: E402
from feed_twin.io.measured import load_measured, segment  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DURATION_S = 20.0
RUNS = 3
HIDDEN = {"coulomb_friction": {"F_c_N": 15.0}, "constant_force": {"f_0_N": -20.0}}


def long_program() -> str:
    """The synthetic program's moves three times (header once, M30 once)."""
    lines = PROGRAM.splitlines()
    moves = [ln for ln in lines[2:] if ln and ln != "M30"]
    return "\n".join(lines[:2] + moves * 3 + ["M30", ""])


def main() -> None:
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        columns = generate(nominal, HIDDEN, program=long_program())
        map_path = write_csv(Path(tmp) / "run.csv", columns, nominal)
        run = load_measured(Path(tmp) / "run.csv", map_path)
    run = segment(run, run.t_s[0], run.t_s[0] + DURATION_S)
    start = time.perf_counter()
    diagnose(run, nominal)  # warm-up: compiles (or loads from the cache) what the runs meet
    warmup = time.perf_counter() - start
    load_before = os.getloadavg()[0]
    times, cpu, names, simulations = [], [], [], 0.0
    for _ in range(RUNS):
        start, start_cpu = time.perf_counter(), time.process_time()
        d, _, _ = diagnose(run, nominal)
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
        names = [e.name for e in d.effects]
        simulations = d.search["simulations"]
    result = {
        "samples": len(run.t_s),
        "duration_s": float(run.t_s[-1] - run.t_s[0]),
        "warmup_s": round(warmup, 3),
        "diagnose_s": [round(t, 3) for t in times],
        "median_s": round(statistics.median(times), 3),
        "cpu_s": [round(t, 3) for t in cpu],
        "median_cpu_s": round(statistics.median(cpu), 3),
        "load_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "cores": os.cpu_count(),
        "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
        "effects": names,
        # the search's cost as the report states it: parameter sets simulated, in batches
        "simulations": simulations,
    }
    print(
        f"diagnose on {result['samples']} samples: median {result['median_s']} s wall, "
        f"{result['median_cpu_s']} s CPU (load {result['load_1min']}), warm-up "
        f"{result['warmup_s']} s, {names}, {simulations:.0f} parameter sets simulated"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
