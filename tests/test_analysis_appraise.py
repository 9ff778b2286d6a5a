"""Intervals, correlations and implausible values of a fit (analysis.uncertainty, .plausible,
.appraise): an interval covers the truth where the model is right, a mass and a torque constant
are said to be correlated, values no machine has are flagged with their likely cause."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.appraise import Appraisal
from feed_twin.analysis.channels import noise_floors, weighted_channels
from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.plausible import implausible
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.report_files import write_report
from feed_twin.analysis.synthetic import Unmodelled, generate, write_csv
from feed_twin.analysis.twin import Twin, drive_from_run
from feed_twin.analysis.uncertainty import Estimates, estimates, sensitivity
from feed_twin.io.measured import load_measured
from feed_twin.plant.effect_api import FreeParameter

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"
# the truth is the twin itself plus the hidden effect: no model error, only noise and the
# encoder's counts, so a 95 % interval must cover the truth
EXACT = Unmodelled(current_lag_s=0.0, coupling_stiffness_factor=1.0, seed=3)


def _run(tmp_path: Path, hidden: dict, unmodelled: Unmodelled = EXACT):
    nominal = ModelDoc.load(EMPS)
    columns = generate(nominal, hidden, unmodelled=unmodelled)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    return nominal, load_measured(tmp_path / "run.csv", map_path)


def test_the_interval_of_a_found_effect_covers_the_truth(tmp_path):
    nominal, run = _run(tmp_path, {"coulomb_friction": {"F_c_N": 15.0}})
    d, _, motion = diagnose(run, nominal)
    (found,) = d.effects
    low, high = found.intervals["F_c_N"]
    assert low < 15.0 < high, (low, found.parameters, high)
    assert 0.0 < high - low < 0.05 * 15.0  # an interval, not a shrug
    fitted = d.appraisal["parameters"]
    assert set(fitted) >= {"table.m", "friction.F_c"}, fitted
    for p in fitted.values():
        assert p["low"] < p["value"] < p["high"], p
    assert d.appraisal["simulations"] == len(fitted) + 1  # one batch of sensitivities
    write_report(d, tmp_path / "out", v_m_s=motion.v_m_s)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["effects"][0]["intervals"]["F_c_N"] == [low, high]
    text = (tmp_path / "out" / "report.md").read_text()
    assert "## How far to trust the fit" in text and "- table.m: " in text, text
    # the search's cost: every fit's simulations, the appraisal's batch among them
    assert d.search["simulations"] > d.appraisal["simulations"] + 6, d.search
    assert d.search["seconds"] >= d.timings_s["appraise_s"]
    assert f"Search: {d.search['simulations']:.0f} parameter sets simulated" in text


def test_mass_and_torque_constant_are_said_to_be_correlated(tmp_path):
    nominal, run = _run(tmp_path, {})
    drive = drive_from_run(run)
    twin = Twin.compile(nominal)
    out = twin.simulate(drive, twin.nominal[None, :])
    meas = weighted_channels(run, out, 1, noise_floors(run, out))
    free = [
        FreeParameter(name=slot, initial=nominal.get(slot), scale=abs(nominal.get(slot)))
        for slot in ("table.m", "drive.gain")
    ]
    s = sensitivity(twin, drive, free, meas, run.t_s)
    assert s is not None
    est = estimates(s)
    ((a, b, rho),) = est.correlated()
    assert {a, b} == {"table.m", "drive.gain"} and abs(rho) > 0.9, rho
    lines = Appraisal(correlated=({"a": a, "b": b, "correlation": rho},)).lines()
    assert lines[0].startswith(f"- correlated: {a} and {b} ({rho:+.3f}): the record fixes")


def test_the_delta_method_adds_variances_and_covariances():
    cov = np.array([[4.0, 1.0], [1.0, 9.0]])
    est = Estimates(names=("a", "b"), values=np.array([1.0, 2.0]), covariance=cov)
    value, low, high = est.interval(lambda v: v["a"] + v["b"] + v["c"], {"c": 10.0})
    assert value == pytest.approx(13.0)
    assert high - value == pytest.approx(1.959964 * math.sqrt(4 + 9 + 2), rel=1e-4)
    assert low == pytest.approx(2 * value - high)


def _effect(name: str, **parameters: float) -> FoundEffect:
    return FoundEffect(
        name=name, evidence="", parameters=parameters, explained_fraction=0.5, component=""
    )


def test_a_mass_eight_times_the_slides_is_flagged_with_the_effort_scale():
    nominal = ModelDoc.load(EMPS)
    m = nominal.get("table.m")
    final = nominal.set("table.m", 8.0 * m)
    (flag,) = implausible(
        nominal, final, ["table.m"], [], v_max_m_s=0.15, correlated={"table.m": ["drive.gain"]}
    )
    assert flag.startswith(f"table.m = {8 * m:.4g} is 8 x its nominal {m:.4g}: implausible")
    assert "effort's scale" in flag and "correlated with drive.gain" in flag, flag
    assert (
        implausible(
            nominal, nominal.set("table.m", 1.5 * m), ["table.m"], [], v_max_m_s=0.15, correlated={}
        )
        == []
    )


def test_a_force_above_the_weight_and_a_stribeck_speed_above_the_record_are_flagged():
    nominal = ModelDoc.load(EMPS)
    weight = 9.80665 * nominal.get("table.m")
    flags = implausible(
        nominal,
        nominal,
        [],
        [_effect("constant_force", f_0_N=4074.0), _effect("stribeck_friction", v_s_m_s=0.4)],
        v_max_m_s=0.15,
        correlated={},
    )
    assert flags == [
        f"constant_force: 4074 N is more than the slide's whole weight (m g = {weight:.4g} N): "
        "implausible; likely cause: an offset of the measured current or the effort's sign",
        "stribeck_friction: the Stribeck speed 0.4 m/s lies above every speed of the record (at "
        "most 0.15 m/s): the law is fitted where it means nothing; likely cause: a friction "
        "that changed over the record (see drift) or a viscous friction",
    ]


def test_a_friction_that_grows_over_the_record_is_named_as_a_drift_with_its_rate(tmp_path):
    """The truth's guide friction grows by 30 % over the record: the drift is an effect of the
    model, friction_drift, fitted with the Coulomb force (its value at the record's start) at
    0.3 / T per second, and the verdict names it; no law of speed takes its place and the
    appraisal finds no drift left."""
    grows = Unmodelled(current_lag_s=0.0, coupling_stiffness_factor=1.0, friction_growth=0.3)
    nominal, run = _run(tmp_path, {"coulomb_friction": {"F_c_N": 15.0}}, grows)
    d = diagnose(run, nominal)[0]
    found = {e.name: e.parameters for e in d.effects}
    assert sorted(found) == ["coulomb_friction", "friction_drift"], d.effects
    duration = float(run.t_s[-1] - run.t_s[0])
    assert found["friction_drift"]["rate_per_s"] == pytest.approx(0.3 / duration, rel=0.10)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(15.0, rel=0.10)
    assert "friction_drift" in d.verdict
    assert d.appraisal["drifts"] == (), d.appraisal["drifts"]


def test_no_drift_is_named_on_a_record_without_one(tmp_path):
    nominal, run = _run(tmp_path, {"mass_error": {"m_kg": 120.0}})
    d = diagnose(run, nominal)[0]
    assert d.appraisal["drifts"] == (), d.appraisal["drifts"]
    assert "changed over the record" not in d.verdict


def test_a_stiffness_56_times_below_nominal_is_flagged_but_a_found_backlash_is_not():
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    k = nominal.get("axial.k_bearing")
    gap = nominal.get("backlash.gap")
    final = nominal.set("axial.k_bearing", k / 56.0).set("backlash.gap", 6.0 * gap)
    slots = ["axial.k_bearing", "backlash.gap"]
    (flag,) = implausible(nominal, final, slots, [], v_max_m_s=0.15, correlated={}, owned=slots)
    assert flag.startswith("axial.k_bearing = ") and "0.0179 x its nominal" in flag, flag
    assert "lost motion (backlash)" in flag, flag
    # the same gap re-fitted as a nominal parameter (no effect owns it) is flagged
    (again,) = implausible(
        nominal, nominal.set("backlash.gap", 6.0 * gap), slots, [], v_max_m_s=0.15, correlated={}
    )
    assert again.startswith("backlash.gap = ") and "6 x its nominal" in again, again
