"""ThermalGrowth: the screw's temperature law and the elongation it puts into the axial chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.analysis.twin import ModelDoc
from feed_twin.core import signals as sig
from feed_twin.plant.config import load_plant
from feed_twin.plant.thermal_growth import (
    ALPHA_STEEL,
    ThermalGrowth,
    temperature_rate,
    with_thermal_growth,
)

GEOMETRY = {
    "arrangement": "fixed-free",
    "E": 2.1e11,
    "d_root": 0.034,
    "L": 1.0,
    "x_0": 0.1,
    "x_min": 0.05,
    "k_bearing": 7.5e8,
    "k_nut": 1.0e9,
}


def test_temperature_rise_at_constant_speed_follows_the_first_order_step_response():
    heating, tau, v, h = 2.0, 60.0, 0.1, 0.05
    f = temperature_rate.py_func
    dT, t = 0.0, 0.0
    for _ in range(2400):  # RK4 over two time constants
        k1 = f(dT, v, heating, tau)
        k2 = f(dT + 0.5 * h * k1, v, heating, tau)
        k3 = f(dT + 0.5 * h * k2, v, heating, tau)
        k4 = f(dT + h * k3, -v, heating, tau)  # direction does not matter: |v| heats
        dT += h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += h
    exact = heating * tau * v * (1.0 - math.exp(-t / tau))
    assert dT == pytest.approx(exact, rel=1e-9)


def test_elongation_shifts_the_relaxed_nut_by_alpha_dT_times_the_heated_length():
    doc, slot = with_thermal_growth(ModelDoc.load("config/axis_default.yaml"), 2.0)
    assert slot == "thermal.heating"
    plant = load_plant(doc.data["plant"], source="thermal test")
    outputs = plant.namespace()["outputs"]
    aux = np.zeros(len(plant.aux_names))
    p = plant.nominal_params()
    lead = 0.01
    for phi, dT in ((3.0, 1.5), (40.0, 4.0)):
        x = plant.initial_state()
        s_ideal = lead / (2.0 * math.pi) * phi
        elongation = ALPHA_STEEL * dT * (GEOMETRY["x_0"] + s_ideal)
        for name in ("motor.phi", "hub_screw.phi", "screw_shaft.phi"):
            x[plant.state_index[name]] = phi
        x[plant.state_index["nut.s"]] = s_ideal + elongation
        x[plant.state_index["table.s"]] = s_ideal + elongation
        x[plant.state_index["thermal.dT"]] = dT
        outputs(0.0, x, p, np.zeros(sig.OUT_SIZE), np.zeros(1), np.zeros(3), aux)
        got = aux[plant.aux_names.index("thermal.elongation")]
        assert got == pytest.approx(elongation, rel=1e-12)
        # the compliance alone pulls the nut back by k e; the thermal element cancels it
        axial = aux[plant.aux_names.index("axial.force")]
        thermal = aux[plant.aux_names.index("thermal.force")]
        k = aux[plant.aux_names.index("axial.stiffness")]
        assert axial == pytest.approx(-k * elongation, rel=1e-9)
        assert axial + thermal == pytest.approx(0.0, abs=1e-6 * abs(axial))


def test_a_model_without_axial_compliance_cannot_grow_thermally():
    with pytest.raises(LookupError, match="no AxialCompliance"):
        with_thermal_growth(ModelDoc.load("config/emps_nominal.yaml"), 1.0)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("alpha", -1e-6, "alpha = -1e-06"),
        ("heating", -1.0, "heating = -1.0"),
        ("tau", 0.0, "tau = 0.0"),
        ("arrangement", "free-free", "arrangement = 'free-free'"),
        ("x_min", 0.0, "x_min = 0.0"),
    ],
)
def test_invalid_parameters_are_refused_with_the_field_named(field, value, message):
    params = {"alpha": ALPHA_STEEL, "heating": 1.0, "tau": 1800.0, **GEOMETRY, field: value}
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        ThermalGrowth(**params)


def test_backlash_edit_needs_a_backlash_component():
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.ranking import Candidate

    cand = Candidate(
        effect=BY_NAME["backlash"],
        variant="",
        explained_fraction=0.9,
        f_statistic=100.0,
        p_value=0.0,
        n_eff=100.0,
        coefficients={"last_direction": 4e-6},
        significant=True,
    )
    with pytest.raises(LookupError, match="no Backlash between a nut mass and the table"):
        BY_NAME["backlash"].edit(ModelDoc.load("config/emps_nominal.yaml"), cand)
    edit = BY_NAME["backlash"].edit(ModelDoc.load("config/axis_default.yaml"), cand)
    # nominal gap 2 um plus twice the half-gap weight
    assert edit.doc.get("backlash.gap") == pytest.approx(2e-6 + 8e-6)
    # without a Backlash, the gap an AxialCompliance declares (tests/test_axial_gap.py)
    edit = BY_NAME["backlash"].edit(ModelDoc.load("config/truth_nominal.yaml"), cand)
    assert edit.doc.get("axial.gap") == pytest.approx(8e-6)
    assert [p.name for p in edit.own] == ["axial.gap"]
