"""The discrepancy workflow blind on the independent truth machine (feed_twin.truth).

Every record comes from a machine the twin did not build (its own current loop, rates,
compliance, friction and trace; feed_twin.truth), with effect sizes drawn at random over
0.5x-2x a typical size from a seed (feed_twin.truth.effects), written as CSV + column map, and
`diagnose` runs on it with only the machine's data sheet, config/truth_nominal.yaml.

- single: each library effect alone, one record per seed. Figures: named first (the first effect
  named is the hidden one; and, apart, the first MACHINE effect named, the record's own
  delays and window aside), and the parameter error: the largest |fit - truth| / |truth| over
  the effect's amplitude parameters (phases and orders left out), of the cases that named it.
- clean: the machine with nothing hidden (noise seeds): figure, the cases that name nothing.
- combo: pairs and triples real machines have, and an effect behind a trace that averages,
  delays and offsets. A case passes when every hidden effect is named, each parameter within
  10 %, and the augmented twin's effort error on a second trajectory (VALIDATION_PROGRAM on the
  same machine) is within 1.5x of the true model's (the nominal twin with the truth's values set
  by the library's own truth functions). A friction drift is named as the effect
  friction_drift (the guides' friction times 1 + rate t, fitted with the others: its rate and
  the friction at the record's start within 10 % of the truth's), or else when the appraisal
  says a drift of the guides' friction at a rate within 10 % of the truth's (its share per
  second of the friction at the record's middle, and the friction there). An effect named
  beside the hidden ones is a miss ("X named but not hidden"; listed in each case's "extra").
- verdicts: cases whose verdict says "no significant missing effect" while a residual is more
  than 10x its sample noise (target 0).
- search: parameter sets simulated per case and the joint selection's share of them.
The last line is one JSON object {"single", "clean", "combo", "verdicts", "search", "cases"}.

    .venv/bin/python benchmarks/blind_truth.py                     # all, 3 seeds, 2 processes
    .venv/bin/python benchmarks/blind_truth.py --seeds 1 --only coulomb_friction clean
    .venv/bin/python benchmarks/blind_truth.py --groups combo --jobs 1
"""

from __future__ import annotations

import argparse
import json
import math
import re
import statistics
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from multiprocessing import Pool
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
NOMINAL_CONFIG = ROOT / "config" / "truth_nominal.yaml"
SEEDS = (101, 102, 103)  # the tests use other seeds (tests/test_truth_machine.py: 7)
REL = 0.10
VALIDATION_RATIO = 1.5
NOISE_RATIO = 10.0
MID_RECORD_S = 6.4  # [s] the middle of a PROGRAM record: where a drifting friction is its mean
NOT_AMPLITUDES = ("phase_rad", "order")
# the effects a friction drift grows (their truth at the record's middle), and the nominal
# twin's friction component (config/truth_nominal.yaml), whose drift the report must say
DRIFTING = ("coulomb_friction", "viscous_friction")
FRICTION_COMPONENT = "guides"
SINGLE = (
    "coulomb_friction",
    "viscous_friction",
    "stribeck_friction",
    "asymmetric_friction",
    "constant_force",
    "mass_error",
    "torque_constant_error",
    "measurement_delay",
    "stiction",
    "backlash",
    "lead_error",
    "position_dependent_stiffness",
    "thermal_drift",
    "cogging_torque",
    "current_offset",
    "dead_time",
)


@dataclass(frozen=True, kw_only=True)
class Case:
    name: str
    group: str  # single | clean | combo
    effects: tuple[str, ...]
    seed: int
    trace: dict[str, Any] = field(default_factory=dict)  # feed_twin.truth.Trace settings
    # trace effects the workflow should name, with their truth (not machine effects)
    record_effects: dict[str, dict[str, float]] = field(default_factory=dict)


COMBOS = {
    "weight+viscous": ("constant_force", "viscous_friction"),
    "coulomb+backlash": ("coulomb_friction", "backlash"),
    "force+asymmetric": ("constant_force", "asymmetric_friction"),
    "coulomb+drift": ("coulomb_friction", "friction_drift"),
    "viscous+drift": ("viscous_friction", "friction_drift"),
    "weight+coulomb+mass": ("constant_force", "coulomb_friction", "mass_error"),
}


def cases(seeds: tuple[int, ...]) -> list[Case]:
    out = [
        Case(name=f"{e}@{s}", group="single", effects=(e,), seed=s) for e in SINGLE for s in seeds
    ]
    out += [Case(name=f"clean@{s}", group="clean", effects=(), seed=s) for s in seeds]
    seed = seeds[0]
    out += [Case(name=n, group="combo", effects=e, seed=seed) for n, e in COMBOS.items()]
    out.append(
        Case(
            name="coulomb behind an averaged, delayed, offset trace",
            group="combo",
            effects=("coulomb_friction", "current_offset"),
            seed=seed,
            trace={"average": True, "delay_effort_s": 2e-3},
            record_effects={"channel_delay": {"delay_s": 2e-3}},
        )
    )
    return out


def _observable(effect: str, truth: dict[str, float]) -> dict[str, float]:
    """The truth as a record can show it: the three phase sensors' common offset is invisible
    in the rotor frame (Park's transform of equal phase offsets is zero), so it is removed."""
    if effect != "current_offset":
        return truth
    common = sum(truth.values()) / len(truth)
    return {k: v - common for k, v in truth.items()}


def _amplitude_error(found: dict[str, float], truth: dict[str, float]) -> float:
    errs = [
        abs(found.get(k, math.nan) - v) / abs(v)
        for k, v in truth.items()
        if k not in NOT_AMPLITUDES and v != 0.0
    ]
    return max(errs) if errs else 0.0


def _true_model(hidden: dict[str, dict[str, float]], nominal: Any) -> tuple[Any, list[str]]:
    """The nominal twin with the truth's values set by the library's truth functions, and the
    effects the nominal model cannot carry (no component for them: left out of the model)."""
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.model_doc import model_of

    doc, missing = nominal, []
    for name, sizes in hidden.items():
        try:
            doc = model_of(BY_NAME[name].truth(doc, sizes))
        except (KeyError, LookupError):  # not a library effect, or no component to carry it
            missing.append(name)
    return doc, missing


def _validation_errors(
    case: Case, hidden: dict, final: Any, nominal: Any, folder: Path
) -> tuple[float, float, list[str]]:
    """Effort rel. error [%] on the second trajectory: (augmented twin, true model, the effects
    the true model could not carry)."""
    from feed_twin.analysis.diagnose import run_metrics
    from feed_twin.analysis.twin import Twin, drive_from_run
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import VALIDATION_PROGRAM, Trace, make_record

    rec = make_record(
        folder / "validation.csv",
        hidden=hidden,
        trace=Trace(**case.trace),
        program=VALIDATION_PROGRAM,
        seed=case.seed + 1000,
    )
    run = load_measured(rec.csv, rec.map)
    drive = drive_from_run(run)
    true_doc, missing = _true_model(hidden | case.record_effects, nominal)
    errs = []
    for doc in (final, true_doc):
        twin = Twin.compile(doc)
        out = twin.simulate(drive, twin.nominal[None, :])
        errs.append(run_metrics(run, out).effort_rel_err_pct if out.ok[0] else math.inf)
    return float(errs[0] or math.nan), float(errs[1] or math.nan), missing


def _noise_ratios(verdict: str) -> list[float]:
    return [float(x) for x in re.findall(r"= ([0-9.e+]+) x its sample noise", verdict)]


def run_case(case: Case) -> dict[str, Any]:
    from feed_twin.analysis.diagnose import diagnose
    from feed_twin.analysis.model_doc import ModelDoc
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import Trace, draw_all, make_record

    clock = time.perf_counter()
    hidden = draw_all(case.effects, case.seed)
    result: dict[str, Any] = {"group": case.group, "hidden": hidden}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            rec = make_record(
                Path(tmp) / "run.csv", hidden=hidden, trace=Trace(**case.trace), seed=case.seed
            )
            nominal = ModelDoc.load(NOMINAL_CONFIG)
            d, final, _ = diagnose(load_measured(rec.csv, rec.map), nominal)
            named = [e.name for e in d.effects]
            found = {e.name: e.parameters for e in d.effects}
            text = json.dumps(d.as_dict()["verdict"]) + json.dumps(d.as_dict()["notes"])
            result |= {
                "named": named,
                "parameters": found,
                "named_not_fitted": [u["name"] for u in d.named_not_fitted],
                "verdict": d.verdict,
                "drift_said": "drift" in text.lower() or any("drift" in n for n in named),
                "drifts": [
                    {k: x[k] for k in ("parameter", "value", "rate_per_s")}
                    for x in d.appraisal.get("drifts", ())
                ],
                "simulations": d.search.get("simulations", 0.0),
                "joint_simulations": d.search.get("joint_simulations", 0.0),
                "effort_before_pct": d.before.effort_rel_err_pct,
                "effort_after_pct": d.after.effort_rel_err_pct,
            }
            if case.group == "combo":
                result["validation_pct"] = _validation_errors(
                    case, hidden, final, nominal, Path(tmp)
                )
    except Exception:  # a case that breaks the workflow is a result, not a crash
        where = " | ".join(traceback.format_exc().strip().splitlines()[-3:])
        result |= {"named": [], "parameters": {}, "verdict": "", "error": where[:400]}
    result["seconds"] = round(time.perf_counter() - clock, 1)
    result["ok"], result["misses"] = _judge(case, result)
    return result


def _judge(case: Case, r: dict[str, Any]) -> tuple[bool, list[str]]:
    misses = []
    named, found = r["named"], r["parameters"]
    if "error" in r:
        return False, [r["error"]]
    if case.group == "clean":
        return not named, [f"named {named}"] if named else []
    if case.group == "single":
        effect = case.effects[0]
        if not named or named[0] != effect:
            misses.append(f"named {named}")
        err = _amplitude_error(found.get(effect, {}), _observable(effect, r["hidden"][effect]))
        r["parameter_error"] = err if effect in found else None
        if effect in found and not err <= REL:
            misses.append(f"parameter error {err:.3g}")
        return not misses, misses
    expected = dict(r["hidden"]) | case.record_effects
    # an effect named beside the hidden ones is a wrong name, not a harmless extra
    r["extra"] = [n for n in named if n not in expected]
    misses += [f"{n} named but not hidden" for n in r["extra"]]
    drift_fitted = "friction_drift" in found
    for effect, truth in expected.items():
        if effect == "friction_drift" and not drift_fitted:
            misses += _drift_misses(r, truth["rate_per_s"])
            continue
        if effect not in found:
            misses.append(f"{effect} not named")
            continue
        if effect in DRIFTING and "friction_drift" in expected and not drift_fitted:
            # said after the fit (the appraisal): the fit holds the friction's mean
            rate = expected["friction_drift"]["rate_per_s"]
            truth = {k: v * (1.0 + rate * MID_RECORD_S) for k, v in truth.items()}
        err = _amplitude_error(found[effect], _observable(effect, truth))
        if not err <= REL:
            misses.append(f"{effect} parameter error {err:.3g}")
    aug, true, _ = r.get("validation_pct", (math.nan, math.nan, []))
    if not aug <= VALIDATION_RATIO * true:
        misses.append(f"validation effort error {aug:.3g} % vs true model {true:.3g} %")
    return not misses, misses


def _drift_misses(r: dict[str, Any], rate: float) -> list[str]:
    """A friction drift must be said, as a drift of the guides' friction (every term, or one
    of them), at a rate within REL of the truth's: its share per second of the friction at
    the record's middle, rate / (1 + rate MID_RECORD_S)."""
    if not r["drift_said"]:
        return ["drift not said"]
    guides = [d for d in r.get("drifts", []) if d["parameter"].startswith(FRICTION_COMPONENT)]
    if not guides:
        return [f"no drift of {FRICTION_COMPONENT} ({[d['parameter'] for d in r['drifts']]})"]
    d = guides[0]
    share = d["rate_per_s"] if d["parameter"].endswith(".*") else d["rate_per_s"] / d["value"]
    truth = rate / (1.0 + rate * MID_RECORD_S)
    err = abs(share - truth) / truth
    return [] if err <= REL else [f"drift rate error {err:.3g}"]


def _search_cost(results: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Parameter sets simulated per case (median, max) and the joint selection's share of all
    of them (analysis.joint), over the cases that ran."""
    ran = [r for r in results.values() if "simulations" in r]
    if not ran:
        return {}
    total = sum(r["simulations"] for r in ran)
    return {
        "simulations_median": statistics.median(r["simulations"] for r in ran),
        "simulations_max": max(r["simulations"] for r in ran),
        "joint_share_pct": round(100.0 * sum(r["joint_simulations"] for r in ran) / total, 1),
    }


def _verdict_misses(results: dict[str, dict[str, Any]]) -> list[str]:
    return [
        name
        for name, r in results.items()
        if r.get("verdict", "").startswith("no significant missing effect")
        and any(x > NOISE_RATIO for x in _noise_ratios(r["verdict"]))
    ]


def _machine_effects(named: list[str]) -> list[str]:
    """The named effects that are the machine's, the record's own (delays, window) left out."""
    from feed_twin.analysis.effects import RECORD_EFFECTS

    record = {e.name for e in RECORD_EFFECTS}
    return [n for n in named if n not in record]


def summary(results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    single = {k: r for k, r in results.items() if r["group"] == "single"}
    first = [k for k, r in single.items() if r["named"][:1] == [k.split("@")[0]]]
    first_machine = [
        k for k, r in single.items() if _machine_effects(r["named"])[:1] == [k.split("@")[0]]
    ]
    errs = [r["parameter_error"] for r in single.values() if r.get("parameter_error") is not None]
    clean = {k: r for k, r in results.items() if r["group"] == "clean"}
    combo = {k: r for k, r in results.items() if r["group"] == "combo"}
    return {
        "single": {
            "cases": len(single),
            "named_first": len(first),
            "named_first_pct": round(100.0 * len(first) / max(len(single), 1), 1),
            "median_parameter_error_pct": round(100.0 * statistics.median(errs), 2)
            if errs
            else None,
            "missed": sorted(set(single) - set(first)),
            # the first MACHINE effect named is the hidden one (the record's delays aside)
            "machine_named_first": len(first_machine),
            "machine_missed": sorted(set(single) - set(first_machine)),
        },
        "clean": {
            "cases": len(clean),
            "nothing_named": sum(1 for r in clean.values() if not r["named"]),
            "no_machine_effect_named": sum(
                1 for r in clean.values() if not _machine_effects(r["named"])
            ),
            "named": {k: r["named"] for k, r in clean.items() if r["named"]},
        },
        "combo": {
            "cases": len(combo),
            "passed": sorted(k for k, r in combo.items() if r["ok"]),
            "failed": {k: r["misses"] for k, r in combo.items() if not r["ok"]},
        },
        "verdicts": {"no_effect_above_10x_noise": _verdict_misses(results)},
        "diagnose_median_s": round(statistics.median(r["seconds"] for r in results.values()), 1),
        "search": _search_cost(results),
    }


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seeds", type=int, default=len(SEEDS), help="seeds per effect (1-3)")
    ap.add_argument("--groups", nargs="*", default=["single", "clean", "combo"])
    ap.add_argument("--only", nargs="*", default=[], help="case names or effect names to keep")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    chosen = [
        c
        for c in cases(SEEDS[: max(1, args.seeds)])
        if c.group in args.groups
        and (not args.only or c.name in args.only or c.name.split("@")[0] in args.only)
    ]
    if not chosen:
        raise SystemExit("no case chosen; see --only and --groups")
    clock = time.perf_counter()
    results: dict[str, dict[str, Any]] = {}
    with Pool(max(1, args.jobs)) as pool:
        for case, r in zip(chosen, pool.imap(run_case, chosen), strict=True):
            results[case.name] = r
            print(
                f"{case.name}: {'ok' if r['ok'] else 'FAIL'} named {r['named']} "
                f"{r['misses']} {r['seconds']} s"
            )
            sys.stdout.flush()
    out = summary(results)
    out["wall_s"] = round(time.perf_counter() - clock, 1)
    out["cases"] = results
    print(json.dumps(out, default=float))


if __name__ == "__main__":
    main(sys.argv[1:])
