"""Shop-floor logs: what the workflow names from a 10 Hz record rounded for display.

Records of the independent truth machine (feed_twin.truth: its own current loop, friction,
gravity and inertia laws, sharing no code with the twin) running a 100 s shop-floor program
(moves at 300-9000 mm/min with dwells, `program()`), with a vertical axis' weight, Coulomb and
viscous friction and a mass error hidden, their sizes drawn 0.5x-2x typical from each seed
(truth.effects). The trace writes what a monitoring system logs: one row every 100 ms, the set
and actual positions rounded to 1 mm or 0.1 mm, the current to 10 mA. Each record is diagnosed
against the truth machine's data sheet (config/truth_nominal.yaml), in-process.

Figures per case: what the record said it cannot see; each hidden effect either named with its
parameter's error, or listed as not visible (then it must never be named), or said to show
too little to be named (visibility.too_small: its signature under the 5 % an effect must
remove, counted with the not visible); what else was named;
the diagnose time (rows ~1000). Last printed line: one JSON object.

    .venv/bin/python benchmarks/slow_records.py [--seeds 11 12 13] [--resolutions 1e-3 1e-4]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured
from feed_twin.truth import Trace, draw_all, make_record

ROOT = Path(__file__).resolve().parent.parent
NOMINAL = ROOT / "config" / "truth_nominal.yaml"
HIDDEN = ("constant_force", "coulomb_friction", "viscous_friction", "mass_error")
# the parameter each effect is judged by (the workflow's report key = the truth's)
KEY = {
    "constant_force": "f_0_N",
    "coulomb_friction": "F_c_N",
    "viscous_friction": "F_v_N_s_m",
    "mass_error": "m_kg",
}
TOLERANCE = 0.10  # a named parameter within 10 % of the truth
PERIOD_S = 0.1  # 10 Hz
DURATION_S = 100.0  # [s] about 1000 rows


def program(duration_s: float = DURATION_S) -> str:
    """A shop-floor day in miniature: moves between stations at cutting feeds and rapids, with
    dwells, for about `duration_s` seconds."""
    stations = (20, 150, 60, 280, 10, 200, 120, 250, 40, 180)
    feeds = (600, 1200, 2400, 4800, 9000, 300, 1800, 7200, 900, 3600)  # mm/min
    lines = ["(a shop-floor program for the 10 Hz log)", "G21 G90 G94 G54 G64", "G1 X0 F3000"]
    x, t, k = 0.0, 0.0, 0
    while t < duration_s:
        target, feed = stations[k % len(stations)], feeds[(3 * k) % len(feeds)]
        lines.append(f"G1 X{target} F{feed}")
        t += abs(target - x) / feed * 60.0 + 0.1
        lines.append("G4 P0.8")
        t += 0.8
        x, k = target, k + 1
    return "\n".join([*lines, "M30", ""])


def one(seed: int, resolution_m: float, workdir: Path) -> dict[str, object]:
    hidden = draw_all(list(HIDDEN), seed)
    trace = Trace(
        period_s=PERIOD_S,
        position_resolution_m=resolution_m,
        command_resolution_m=resolution_m,
        effort_noise_A=0.02,
        effort_resolution_A=0.01,
    )
    rec = make_record(
        workdir / f"log_{seed}_{resolution_m:g}.csv",
        hidden=hidden,
        trace=trace,
        program=program(),
        seed=seed,
    )
    run = load_measured(rec.csv, rec.map)
    doc = ModelDoc.load(NOMINAL)
    clock, cpu = time.perf_counter(), time.process_time()
    diagnosis, _, _ = diagnose(run, doc, model_path=str(workdir / "model.yaml"))
    elapsed, cpu = time.perf_counter() - clock, time.process_time() - cpu
    vis = diagnosis.visibility or {}
    unseen = dict(vis.get("cannot_be_seen", {}))
    named = {e.name: e.parameters for e in diagnosis.effects}
    # a visible effect whose signature shows but is too small to name, said so: listed
    unseen.update(vis.get("too_small", {}))
    effects: dict[str, object] = {}
    for name in HIDDEN:
        truth = hidden[name][KEY[name]]
        if name in unseen:
            effects[name] = {"visible": False, "named": name in named, "reason": unseen[name]}
            continue
        got = named.get(name, {}).get(KEY[name])
        err = None if got is None else abs(got - truth) / abs(truth)
        effects[name] = {
            "visible": True,
            "named": got is not None,
            "truth": truth,
            "fitted": got,
            "error": err,
            "within": err is not None and err <= TOLERANCE,
        }
    return {
        "seed": seed,
        "resolution_m": resolution_m,
        "rows": len(run.t_s),
        "diagnose_s": elapsed,
        "diagnose_cpu_s": cpu,
        "effects": effects,
        "also_named": sorted(set(named) - set(HIDDEN)),
        "cannot_be_seen": sorted(unseen),
        "verdict": diagnosis.verdict,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description="diagnose 10 Hz truth-machine logs")
    parser.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13])
    parser.add_argument("--resolutions", type=float, nargs="+", default=[1e-3, 1e-4])
    args = parser.parse_args()
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        for q in args.resolutions:
            for seed in args.seeds:
                case = one(seed, q, Path(tmp))
                cases.append(case)
                parts = []
                for name, e in case["effects"].items():  # type: ignore[union-attr]
                    if not e["visible"]:
                        what = "too small" if e["reason"].startswith("not named") else "not visible"
                        parts.append(f"{name}: {what}{', NAMED' if e['named'] else ''}")
                    elif e["named"]:
                        parts.append(f"{name}: {e['fitted']:.4g} vs {e['truth']:.4g}")
                    else:
                        parts.append(f"{name}: MISSED")
                print(
                    f"q {q * 1e3:g} mm, seed {seed}, {case['rows']} rows, "
                    f"{case['diagnose_s']:.1f} s (CPU {case['diagnose_cpu_s']:.1f} s): "
                    + "; ".join(parts)
                    + (f"; also named {case['also_named']}" if case["also_named"] else ""),
                    flush=True,
                )
    visible = [e for c in cases for e in c["effects"].values() if e["visible"]]  # type: ignore[union-attr]
    hidden_unseen = [e for c in cases for e in c["effects"].values() if not e["visible"]]  # type: ignore[union-attr]
    times = [float(c["diagnose_s"]) for c in cases]  # type: ignore[arg-type]
    summary = {
        "cases": len(cases),
        "visible_effects": len(visible),
        "visible_named_within_10pct": sum(1 for e in visible if e["within"]),
        "visible_named": sum(1 for e in visible if e["named"]),
        "not_visible": len(hidden_unseen),
        "not_visible_but_named": sum(1 for e in hidden_unseen if e["named"]),
        "also_named": sorted({n for c in cases for n in c["also_named"]}),  # type: ignore[union-attr]
        "median_error": float(np.median([e["error"] for e in visible if e["error"] is not None]))
        if any(e["error"] is not None for e in visible)
        else None,
        "diagnose_s_median": float(np.median(times)),
        "diagnose_s_max": float(np.max(times)),
        "diagnose_cpu_s_median": float(np.median([c["diagnose_cpu_s"] for c in cases])),  # type: ignore[arg-type]
        "load_average": os.getloadavg(),
        "rows": [c["rows"] for c in cases],
        "details": cases,
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
