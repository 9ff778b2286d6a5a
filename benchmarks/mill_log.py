"""Cost of `diagnose` on the real 10 Hz mill log against the default 16 kHz axis model.

The log (tests/fixtures/umich_mill/experiment_01.csv, X, 1055 rows, current in A:
x_map_axis.yaml) diagnosed against config/axis_default.yaml (PMSM, inverter and current loop at
16 kHz, coupling, screw in torsion, axial springs, backlash). As written, the model costs 1.7
million ticks per simulated parameter set on this log, and the workflow simulates hundreds of
sets: that, not the record, set the cost (356-376 s). At the record's scale
(feed_twin.analysis.record_scale: the same axis without its current loop, rigid but for the
lossy screw's axial spring, at its velocity loop's 8 kHz) each set costs a fraction of it.

Figures: wall and CPU seconds of `diagnose` at the record's scale (`scaled`), the parameter sets
simulated, what it named; with --full the same on the model as written (`full`, minutes). With
--cross-check SECONDS both on the log's first SECONDS only, and the named parameters' relative
differences (the reduction's answer against the full model's). Last printed line: one JSON
object.

    .venv/bin/python benchmarks/mill_log.py [--full] [--cross-check 30]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as `feed-twin diagnose` runs

from feed_twin.analysis.diagnose import diagnose  # noqa: E402
from feed_twin.analysis.rounds import Options  # noqa: E402
from feed_twin.analysis.twin import ModelDoc  # noqa: E402
from feed_twin.io.measured import load_measured, segment  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MILL = ROOT / "tests" / "fixtures" / "umich_mill"
NOMINAL = ROOT / "config" / "axis_default.yaml"


def one(seconds: float | None, *, scaled: bool, workdir: Path) -> dict[str, object]:
    run = load_measured(MILL / "experiment_01.csv", MILL / "x_map_axis.yaml")
    if seconds is not None:
        run = segment(run, 0.0, seconds)
    clock, cpu = time.perf_counter(), time.process_time()
    diagnosis, _, _ = diagnose(
        run,
        ModelDoc.load(NOMINAL),
        options=Options(record_scale=scaled),
        model_path=str(workdir / "model.yaml"),
    )
    said = (diagnosis.visibility or {}).get("said", [])
    return {
        "model": "record scale" if scaled else "as written",
        "rows": len(run.t_s),
        "wall_s": time.perf_counter() - clock,
        "cpu_s": time.process_time() - cpu,
        "simulations": diagnosis.search["simulations"] if diagnosis.search else None,
        "named": {e.name: e.parameters for e in diagnosis.effects},
        "scale_line": next((s for s in said if "record's scale" in s), None),
        "effort_error_before_pct": diagnosis.before.effort_rel_err_pct,
        "effort_error_after_pct": diagnosis.after.effort_rel_err_pct,
    }


def _differences(a: dict, b: dict) -> dict[str, float]:
    """Relative differences of the parameters both runs named (a against b)."""
    out = {}
    for name, params in a.items():
        for key, value in params.items():
            other = b.get(name, {}).get(key)
            if other is not None and other != 0.0:
                out[f"{name}.{key}"] = abs(value - other) / abs(other)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description="diagnose the 10 Hz mill log on the 16 kHz axis")
    parser.add_argument("--full", action="store_true", help="also on the model as written")
    parser.add_argument("--cross-check", type=float, metavar="SECONDS", help="both, on a part")
    args = parser.parse_args()
    load = [os.getloadavg()[0]]
    runs: dict[str, object] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        runs["scaled"] = one(None, scaled=True, workdir=work)
        print(f"record scale: {json.dumps(runs['scaled'])}", flush=True)
        if args.full:
            runs["full"] = one(None, scaled=False, workdir=work)
            print(f"as written: {json.dumps(runs['full'])}", flush=True)
        if args.cross_check:
            part = {s: one(args.cross_check, scaled=s, workdir=work) for s in (True, False)}
            runs["cross_check"] = {
                "seconds": args.cross_check,
                "scaled": part[True],
                "full": part[False],
                "differences": _differences(part[True]["named"], part[False]["named"]),  # type: ignore[arg-type]
            }
            print(f"cross-check: {json.dumps(runs['cross_check'])}", flush=True)
    load.append(os.getloadavg()[0])
    print(json.dumps({"load_1min": load, **runs}))


if __name__ == "__main__":
    main()
