"""Cogging on a twin whose motor is an effort source on an inertia (config/truth_nominal.yaml):
the CoggingTorque component and the cogging_torque effect it carries there."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from twin_support import simulate_command, strong_candidate

from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.analysis.ranking import Candidate
from feed_twin.plant.cogging_torque import CoggingTorque
from feed_twin.plant.pmsm import with_cogging

ROOT = Path(__file__).resolve().parents[1]
TRUTH_NOMINAL = ROOT / "config" / "truth_nominal.yaml"
LEAD = 0.01


def _cruise(doc: ModelDoc, speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The twin at a steady `speed` [m/s] after a 0.1 s raised-cosine start: (t, x, effort)
    from 0.3 s on."""
    h = doc.base_period()
    t = np.arange(0.0, 1.3, h)
    u = np.clip(t / 0.1, 0.0, 1.0)
    x_cmd = 0.2 + np.cumsum(speed * (0.5 - 0.5 * np.cos(np.pi * u))) * h
    out = simulate_command(doc, t, x_cmd)
    assert out.effort is not None
    on = t > 0.3
    return t[on], out.x_m[0][on], out.effort[0][on]


def test_the_drive_supplies_the_cogging_torque_of_an_effort_source_twin():
    """At 6 detents per revolution and a quarter revolution per second (1.5 Hz) the velocity
    loop holds the speed: the drive's torque carries -A sin(6 phi + phase), phi = 2 pi x /
    lead (at one revolution per second the rotor's inertia adds 5 %)."""
    doc = ModelDoc.load(TRUTH_NOMINAL)
    amplitude, phase = 0.05, 0.3
    cogged, prefix = with_cogging(doc, 6, amplitude, phase)
    cogged = model_of(cogged)
    assert prefix == "cogging." and cogged.component("cogging")["type"] == "CoggingTorque"
    _, _, e0 = _cruise(doc, LEAD / 4)
    _, x, e1 = _cruise(cogged, LEAD / 4)
    arg = 6 * 2 * math.pi * x / LEAD + phase
    basis = np.column_stack((np.sin(arg), np.cos(arg)))
    (s, c), *_ = np.linalg.lstsq(basis, e1 - e0, rcond=None)
    assert s == pytest.approx(-amplitude, rel=0.005)
    assert abs(c) < 0.01 * amplitude


def _candidate() -> Candidate:
    return strong_candidate(
        "cogging_torque",
        {"sin": -0.03, "cos": 0.04},
        variant="order 6 per motor revolution",
        force_per_unit=2 * math.pi / LEAD,  # an effort in N m through a 10 mm lead
    )


def test_the_edit_adds_a_cogging_torque_on_the_effort_sources_flange():
    edit = BY_NAME["cogging_torque"].edit(ModelDoc.load(TRUTH_NOMINAL), _candidate())
    wires = edit.doc.data["plant"]["connect"]
    assert ["cogging.flange", "drive.flange"] in wires
    assert edit.doc.get("cogging.order") == 6.0
    assert edit.doc.get("cogging.amplitude") == pytest.approx(0.05)  # hypot of the weights
    assert edit.doc.get("cogging.phase") == pytest.approx(math.atan2(-0.04, 0.03))
    assert [p.name for p in edit.own] == ["cogging.amplitude", "cogging.phase"]


def test_a_translational_effort_source_cannot_carry_cogging():
    emps = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    with pytest.raises(LookupError, match="no Pmsm, nor an EffortSource on a rotor flange"):
        BY_NAME["cogging_torque"].edit(emps, _candidate())


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"order": 0, "amplitude": 0.1, "phase": 0.0}, "order = 0: must be a whole number >= 1"),
        ({"order": 6, "amplitude": -0.1, "phase": 0.0}, "amplitude"),
        ({"order": 6, "amplitude": 0.1, "phase": math.inf}, "phase"),
    ],
)
def test_cogging_torque_parameters_are_checked(params, message):
    with pytest.raises(ValueError, match=message):
        CoggingTorque(**params)


@pytest.mark.slow
def test_the_truth_machines_cogging_is_named_on_its_effort_source_twin(tmp_path):
    """The independent truth machine (feed_twin.truth: a PMSM with cogging behind an 8 kHz
    current loop) diagnosed with its data sheet, config/truth_nominal.yaml (an effort source on
    an inertia): the cogging is named first, order 6, amplitude within 10 % (the twin's 1 kHz
    loops against the drive's faster ones leave 4 % at seed 7)."""
    from feed_twin.analysis.diagnose import diagnose
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import draw_all, make_record

    hidden = draw_all(["cogging_torque"], seed=7)
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=7)
    d = diagnose(load_measured(rec.csv, rec.map), ModelDoc.load(TRUTH_NOMINAL))[0]
    assert [e.name for e in d.effects][:1] == ["cogging_torque"], d.notes
    found = d.effects[0].parameters
    assert found["order"] == 6.0
    truth = hidden["cogging_torque"]["amplitude_Nm"]
    assert found["amplitude_Nm"] == pytest.approx(truth, rel=0.10)
