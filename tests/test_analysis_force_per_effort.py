"""Newtons at the table per unit of the drive's effort (ModelDoc.force_per_effort), the one
factor the discrepancy workflow's edits and the shadow twin's parameter estimates share:
closed forms, then the compiled twin itself as the second path."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.twin import Drive, Twin
from feed_twin.shadow.twin import physical_effects

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
EMPS = ROOT / "config" / "emps_nominal.yaml"
# axis_default: a PMSM with 4 pole pairs and psi_pm 0.3167 V s, a 10 mm screw of efficiency 0.9
K_T = 1.5 * 4 * 0.3167  # [N m/A]
LEAD, ETA = 0.01, 0.9


def test_closed_forms_of_a_current_a_torque_and_a_force():
    doc = ModelDoc.load(AXIS)
    # friction: the screw drives the load, c = 1/eta
    assert doc.force_per_effort("A") == pytest.approx(K_T * 2 * math.pi / LEAD * ETA, rel=1e-12)
    assert doc.force_per_effort("N m") == pytest.approx(2 * math.pi / LEAD * ETA, rel=1e-12)
    # inertia or a weight, driven against as often as they drive: c = (1/eta + eta)/2
    both = K_T * 2 * math.pi / LEAD / (0.5 * (1 / ETA + ETA))
    assert doc.force_per_effort("A", resisting=False) == pytest.approx(both, rel=1e-12)
    assert doc.force_per_effort("N") == 1.0
    # the EMPS model has a lossless screw: both cases agree
    emps = ModelDoc.load(EMPS)
    assert emps.force_per_effort("N m") == pytest.approx(2 * math.pi / 0.0025, rel=1e-12)
    assert emps.force_per_effort("N m", resisting=False) == emps.force_per_effort("N m")


def test_the_motors_constant_not_the_controllers_belief():
    """The controller's drive K_t is what it believes; the table feels the motor's."""
    doc = ModelDoc.load(AXIS)
    believed = doc.data["controller"]["drive"]
    believed["K_t"] = 2.5
    assert doc.force_per_effort("A") == pytest.approx(K_T * 2 * math.pi / LEAD * ETA, rel=1e-12)


def test_without_a_screw_there_is_no_factor_and_a_bad_unit_is_named():
    doc = ModelDoc.load(AXIS)
    comps = doc.data["plant"]["components"]
    doc.data["plant"]["components"] = [c for c in comps if c["type"] != "BallScrew"]
    assert doc.force_per_effort("A") is None
    with pytest.raises(ValueError, match=r"effort_unit = 'mA': must be one of 'N', 'N m', 'A'"):
        ModelDoc.load(AXIS).force_per_effort("mA")


def test_the_shadow_twin_converts_with_the_same_factors():
    twin = Twin.compile(ModelDoc.load(AXIS))
    per = {p.effect: p.per_effort for p in physical_effects(twin)}
    assert per["coulomb_friction"] == twin.doc.force_per_effort("A")
    assert per["viscous_friction"] == twin.doc.force_per_effort("A")
    assert per["mass_error"] == twin.doc.force_per_effort("A", resisting=False)
    # the drive supplies the opposite of a constant force
    assert per["constant_force"] == -per["mass_error"]


def _drive(t: np.ndarray, v: float) -> Drive:
    return Drive(
        t_s=t,
        pos_ref_m=0.3 + v * t,
        vel_ref_m_s=np.full_like(t, v),
        acc_ref_m_s2=np.zeros_like(t),
        effort_add=None,
        force_ext_N=None,
        x0_m=0.3,
        sensor="linear_scale",
    )


def test_the_twin_draws_the_current_the_factor_predicts():
    """Second path: the compiled PMSM axis. 50 N more Coulomb friction at a constant 0.1 m/s
    costs 50 N / (K_t 2 pi eta / lead) more q-current: the screw drives the load (a lossless
    screw's factor would be 10 % off, far outside the 1 % tolerance)."""
    twin = Twin.compile(ModelDoc.load(AXIS))
    t = 1e-3 * np.arange(600)
    steady = slice(400, 600)
    params = np.repeat(twin.nominal[None, :], 2, axis=0)
    for side in ("pos", "neg"):
        params[1, twin.index[f"guides.F_c_{side}"]] += 50.0
    out = twin.simulate(_drive(t, 0.1), params)
    assert out.ok.all() and out.effort is not None
    d_i = float(np.mean(out.effort[1, steady] - out.effort[0, steady]))
    force_per_ampere = twin.doc.force_per_effort("A")
    assert force_per_ampere is not None, "the axis model has a screw and a motor"
    assert d_i * force_per_ampere == pytest.approx(50.0, rel=0.01)
