"""Wall time of `diagnose` on a 20 s, 1 kHz record (median of three runs).

The record is a synthetic EMPS run (analysis.synthetic) of the test program played three times
and cut to its first 20 s, with two hidden effects (Coulomb friction and a constant force), so
the workflow goes through two rounds of add-and-fit, the re-examination and the joint re-fit.
A warm-up run compiles every kernel structure first. Target: median <= 10 s.
Last printed line: one JSON object of the figures.

    .venv/bin/python benchmarks/diagnose_record_speed.py
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.synthetic import PROGRAM, generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured, segment

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
    diagnose(run, nominal)  # warm-up: compiles what the runs meet
    times, names = [], []
    for _ in range(RUNS):
        start = time.perf_counter()
        d, _, _ = diagnose(run, nominal)
        times.append(time.perf_counter() - start)
        names = [e.name for e in d.effects]
    result = {
        "samples": len(run.t_s),
        "duration_s": float(run.t_s[-1] - run.t_s[0]),
        "diagnose_s": [round(t, 3) for t in times],
        "median_s": round(statistics.median(times), 3),
        "effects": names,
    }
    print(f"diagnose on {result['samples']} samples: median {result['median_s']} s, {names}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
