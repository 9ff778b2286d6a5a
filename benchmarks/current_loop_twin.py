"""The truth machine's nominal twin three ways, on a clean truth record at the true parameters.

- `ideal`: config/truth_nominal.yaml with an ideal torque source (its current loop's fields
  removed from the EffortSource);
- `loop`: the file as it is, the source behind the drive's current loop (plant.current_loop);
- `stage`: analysis.drive_stage's full electrical stage at zero dead time (Pmsm, averaged
  inverter, current sensor, the controller's sampled current loop one period late).
Figures: position and effort residual RMS against the record, the position's RMS distance to
the stage's, and the cost of one simulation of the 13 s record (median of --repeats).

    .venv/bin/python benchmarks/current_loop_twin.py [--repeats 5]

The last line is one JSON object {name: {...}}.
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    from feed_twin.analysis.drive_stage import expand
    from feed_twin.analysis.model_doc import ModelDoc
    from feed_twin.analysis.twin import Twin, drive_from_run
    from feed_twin.io.measured import load_measured
    from feed_twin.plant.effort_source import CURRENT_LOOP_FIELDS
    from feed_twin.truth import make_record

    ap = argparse.ArgumentParser(description="the truth twin with and without its current loop")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=5, help="the record's noise seed")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        rec = make_record(Path(tmp) / "run.csv", hidden={}, seed=args.seed)
        run = load_measured(rec.csv, rec.map)
    drive = drive_from_run(run)
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    data = copy.deepcopy(doc.data)
    for entry in data["plant"]["components"]:
        if entry["type"] == "EffortSource":
            for name in CURRENT_LOOP_FIELDS:
                entry["params"].pop(name, None)
    ideal = ModelDoc(
        data=data,
        source="ideal",
        ties=doc.ties,
        asymmetric=doc.asymmetric,
        reference_gain=doc.reference_gain,
    )
    effort = run[run.effort_name] if run.effort_name else None
    assert effort is not None
    x, out, cost = {}, {}, {}
    for name, model in (("ideal", ideal), ("loop", doc), ("stage", expand(doc))):
        twin = Twin.compile(model)
        p = twin.nominal[None, :]
        sim = twin.simulate(drive, p)  # compiled and warm
        times = []
        for _ in range(args.repeats):
            clock = time.perf_counter()
            sim = twin.simulate(drive, p)
            times.append(time.perf_counter() - clock)
        x[name] = sim.x_m[0]
        cost[name] = statistics.median(times)
        assert sim.effort is not None
        out[name] = {
            "position_rms_um": float(np.sqrt(np.mean((x[name] - run["pos_meas_m"]) ** 2)) * 1e6),
            "effort_rms_pct": float(
                100.0 * np.sqrt(np.mean((sim.effort[0] - effort) ** 2) / np.mean(effort**2))
            ),
            "seconds_per_simulation": round(cost[name], 4),
            "substeps": int(twin.engine.nsub),
            "base_period_s": twin.base_period_s,
        }
    for name in out:
        out[name]["to_stage_um"] = float(np.sqrt(np.mean((x[name] - x["stage"]) ** 2)) * 1e6)
        out[name]["cost_vs_ideal"] = round(cost[name] / cost["ideal"], 2)
        print(
            f"{name:6s} position {out[name]['position_rms_um']:.3f} um RMS "
            f"(to the stage's {out[name]['to_stage_um']:.3f} um), effort "
            f"{out[name]['effort_rms_pct']:.2f} %, {cost[name] * 1e3:.1f} ms per simulation "
            f"({out[name]['cost_vs_ideal']:.2f}x the ideal source's)"
        )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
