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
--cross-check REPEATS both on a synthetic 10 Hz record of the full axis (the synthetic
program's moves REPEATS times, a Coulomb friction and a weight hidden: a well-posed answer,
where the mill log's slow feeds make a sliding and a viscous force nearly one unknown), and
the named parameters' relative differences (the reduction's answer against the full model's).
Last printed line: one JSON object.

    .venv/bin/python benchmarks/mill_log.py [--full] [--cross-check 4] [--no-log]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as `feed-twin diagnose` runs

from feed_twin.analysis.diagnose import diagnose  # noqa: E402
from feed_twin.analysis.rounds import Options  # noqa: E402
from feed_twin.analysis.synthetic import PROGRAM, generate, write_csv  # noqa: E402
from feed_twin.analysis.twin import ModelDoc  # noqa: E402
from feed_twin.io.measured import MeasuredRun, load_measured  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
MILL = ROOT / "tests" / "fixtures" / "umich_mill"
NOMINAL = ROOT / "config" / "axis_default.yaml"
# hidden in the synthetic record of the cross-check: the guides' friction and a weight
HIDDEN = {"coulomb_friction": {"F_c_N": 250.0}, "constant_force": {"f_0_N": -300.0}}


def one(run: MeasuredRun, *, scaled: bool, workdir: Path) -> dict[str, object]:
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


def synthetic_run(workdir: Path, repeats: int) -> MeasuredRun:
    """A 10 Hz record of the full axis itself (analysis.synthetic: config/axis_default.yaml
    with a guide friction of 250 N instead of 120 N and a weight of -300 N hidden), every
    hundredth 1 ms sample kept, positions rounded to 0.1 mm: the cross-check of the two
    models. Unrounded, the reduction is refused (its following error differs by 19 um at the
    program's 100 mm/s, which a position exact to the micron shows)."""
    nominal = ModelDoc.load(NOMINAL)
    lines = PROGRAM.splitlines()
    moves = [ln for ln in lines[2:] if ln and ln != "M30"]
    program = "\n".join(lines[:2] + moves * repeats + ["M30", ""])
    columns = generate(nominal, HIDDEN, program=program, start_m=0.1)
    slow = {k: v[99::100] for k, v in columns.items()}
    for name in ("x_cmd_mm", "x_act_mm"):  # logged to 0.1 mm, as a monitoring system prints
        slow[name] = np.round(slow[name], 1)
    map_path = write_csv(workdir / "synthetic.csv", slow, nominal)
    return load_measured(workdir / "synthetic.csv", map_path)


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
    parser.add_argument("--no-log", action="store_true", help="not the mill log at its scale")
    parser.add_argument(
        "--cross-check", type=int, metavar="REPEATS", help="both, on a synthetic 10 Hz record"
    )
    args = parser.parse_args()
    load = [os.getloadavg()[0]]
    runs: dict[str, object] = {}
    log = load_measured(MILL / "experiment_01.csv", MILL / "x_map_axis.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if not args.no_log:
            runs["scaled"] = one(log, scaled=True, workdir=work)
            print(f"record scale: {json.dumps(runs['scaled'])}", flush=True)
        if args.full:
            runs["full"] = one(log, scaled=False, workdir=work)
            print(f"as written: {json.dumps(runs['full'])}", flush=True)
        if args.cross_check:
            run = synthetic_run(work, args.cross_check)
            part = {s: one(run, scaled=s, workdir=work) for s in (True, False)}
            runs["cross_check"] = {
                "hidden": HIDDEN,
                "rows": len(run.t_s),
                "scaled": part[True],
                "full": part[False],
                "differences": _differences(part[True]["named"], part[False]["named"]),  # type: ignore[arg-type]
            }
            print(f"cross-check: {json.dumps(runs['cross_check'])}", flush=True)
    load.append(os.getloadavg()[0])
    print(json.dumps({"load_1min": load, **runs}))


if __name__ == "__main__":
    main()
