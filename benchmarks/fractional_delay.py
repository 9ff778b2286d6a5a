"""Where each measure puts the truth machine's feedback delay between the twin's ticks.

Truth records (feed_twin.truth, seeds 5-12, not blind_truth's) with a hidden measurement_delay
of 0.6-4 ms, the nominal twin with the delay's edit; the delay scanned over +-0.6 tick around
the truth's in steps of 0.02 tick, in one batch. For each record the best value by
- J, the fit's cost under the weights set at the nominal twin (analysis.channels), which
  `trials.refined` used before #27's FRACTIONAL_DELAY_BIAS was fixed,
- the channels' likelihood (fit.profile_cost), which it uses now,
- the position channel alone, and the effort channel alone,
each as its offset from the truth [ticks]. docs/diagnose.md, "A delay refined by the channels'
likelihood", says why the effort alone and J sit low.

    .venv/bin/python benchmarks/fractional_delay.py

The last line is one JSON object.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
# (hidden delay [s], seed): the truth delays by whole 0.125 ms current periods, so 0.6 ms is
# 0.625 ms, 2.5 ticks, and 2.7 ms is 2.75 ms, 11 ticks
CASES = ((1.125e-3, 5), (1.0e-3, 7), (2.0e-3, 8), (4.0e-3, 9), (0.6e-3, 11), (2.7e-3, 12))
SPAN, STEP = 0.6, 0.02  # [ticks]
MEASURES = ("J", "likelihood", "position_alone", "effort_alone")


def main() -> None:
    from feed_twin.analysis.channels import noise_floors, weighted_channels
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.fit import cost_of, profile_cost
    from feed_twin.analysis.model_doc import ModelDoc, model_of
    from feed_twin.analysis.ranking import Candidate
    from feed_twin.analysis.twin import Twin, drive_from_run
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import make_record
    from feed_twin.truth.machine import NOMINAL

    nominal = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    effect = BY_NAME["measurement_delay"]
    # the delay's edit as a ranking that found it far above the noise would ask for it
    candidate = Candidate(
        effect=effect,
        coefficients={},
        variant="",
        explained_fraction=0.9,
        f_statistic=1e3,
        p_value=0.0,
        n_eff=1000.0,
        significant=True,
    )
    edit = effect.edit(nominal, candidate)
    twin = Twin.compile(model_of(edit.doc))
    tick = twin.base_period_s
    current_period = 1.0 / NOMINAL.f_current_hz
    began = time.perf_counter()
    rows: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for delay_s, seed in CASES:
            hidden = {"measurement_delay": {"delay_s": delay_s}}
            rec = make_record(Path(tmp) / "run.csv", hidden=hidden, seed=seed)
            run = load_measured(rec.csv, rec.map)
            drive = drive_from_run(run)
            out = twin.simulate(drive, twin.nominal[None, :])
            meas = weighted_channels(run, out, 1, noise_floors(run, out))
            truth = round(delay_s / current_period) * current_period / tick
            grid = np.arange(truth - SPAN, truth + SPAN + 0.5 * STEP, STEP)
            batch = np.repeat(twin.nominal[None, :], len(grid), axis=0)
            for i in twin.index["sensors.delay_ticks"]:
                batch[:, i] = grid
            sims = twin.simulate(drive, batch)
            measures = {
                "J": meas,
                "likelihood": meas,
                "position_alone": dataclasses.replace(meas, effort=None),
                "effort_alone": dataclasses.replace(meas, scale_x=np.inf),
            }
            found = {}
            for name, m in measures.items():
                cost = profile_cost if name == "likelihood" else cost_of
                costs = [cost(m, sims, row) for row in range(len(grid))]
                found[name] = round(float(grid[int(np.argmin(costs))] - truth), 3) + 0.0
            key = f"{truth:g} ticks @{seed}"
            rows[key] = found
            print(f"{key:16s} " + "  ".join(f"{n} {v:+.2f}" for n, v in found.items()))
    worst = {n: max(abs(r[n]) for r in rows.values()) for n in MEASURES}
    print(f"largest offset [ticks]: {worst}")
    summary = {
        "cases": rows,
        "largest_offset_ticks": worst,
        "grid_step_ticks": STEP,
        "seconds": round(time.perf_counter() - began, 1),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
