"""Effects owned by the plant components: declarations, declared quantities, import direction."""

from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path

import pytest

from feed_twin.analysis.effects import BY_NAME, LIBRARY, RECORD_EFFECTS
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.analysis.ranking import Candidate
from feed_twin.plant.axial_compliance import AxialCompliance
from feed_twin.plant.inverter import Inverter
from feed_twin.plant.registry import COMPONENT_TYPES, EFFECTS
from feed_twin.plant.thermal_growth import ALPHA_STEEL as ALPHA

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
EMPS = ROOT / "config" / "emps_nominal.yaml"


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at module level or inside functions."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_no_plant_module_imports_the_analysis():
    offenders = {
        str(path.relative_to(ROOT)): sorted(m for m in _imports(path) if "analysis" in m)
        for path in (ROOT / "feed_twin" / "plant").glob("*.py")
    }
    assert {k: v for k, v in offenders.items() if v} == {}


def test_every_library_effect_is_carried_by_a_registered_component_or_the_record():
    declared = EFFECTS + RECORD_EFFECTS
    assert [e.name for e in LIBRARY] == [e.name for e in declared]
    for used, own in zip(LIBRARY, declared, strict=True):
        # the analysis wraps two effects: current offsets also fit (and are set in) a twin
        # without a current sensor (a torque ripple once per electrical revolution on an
        # effort source's rotor, else a ripple on its effort), and a dead time is carried by
        # the drive's electrical stage in a torque-source twin with a drive data sheet
        # (analysis.drive_stage); everything else is as declared
        assert used == (
            dataclasses.replace(own, edit=used.edit, truth=used.truth)
            if own.name in {"current_offset", "dead_time"}
            else own
        )
    for effect in EFFECTS:
        kind = COMPONENT_TYPES[effect.owner]
        assert effect.name in {e.name for e in kind.EFFECTS}
        assert effect.component.startswith(f"{effect.owner}.")
    assert len(BY_NAME) == len(LIBRARY)  # no name twice


def test_declared_quantities_equal_the_components_own_slots():
    """Two paths to EA, the dead fraction and K_t: the document's (through the declared
    Quantity) and the component's (its slots / the Park torque law)."""
    doc = ModelDoc.load(AXIS)
    axial = doc.component("axial")["params"]
    assert doc.get("axial.EA") == AxialCompliance(**axial).slots()["EA"]
    inverter = doc.component("inverter")["params"]
    assert doc.get("inverter.dead_fraction") == Inverter(**inverter).slots()["dead_fraction"]
    motor = doc.component("motor")["params"]
    assert doc.torque_constant() == pytest.approx(1.5 * motor["p"] * motor["psi_pm"], rel=1e-15)


def test_setting_a_declared_quantity_writes_the_parameters_it_is_made_of():
    doc = ModelDoc.load(AXIS)
    ea = 2.5e8
    new = doc.set("axial.EA", ea)
    params = new.component("axial")["params"]
    assert params["d_root"] == doc.component("axial")["params"]["d_root"]  # diameter kept
    assert params["E"] * math.pi * params["d_root"] ** 2 / 4.0 == pytest.approx(ea, rel=1e-14)
    new = doc.set("inverter.dead_fraction", 0.032)
    f_pwm = new.component("inverter")["params"]["f_pwm"]
    assert new.component("inverter")["params"]["t_dead"] == pytest.approx(0.032 / f_pwm)
    assert doc.has_slot("axial.EA") and not doc.has_slot("motor.cog0_amplitude")


def _weights(effect: str, force_per_unit: float = 1.0, **coefficients: float) -> Candidate:
    return Candidate(
        effect=BY_NAME[effect],
        variant="",
        explained_fraction=0.5,
        f_statistic=100.0,
        p_value=0.0,
        n_eff=100.0,
        coefficients=coefficients,
        significant=True,
        force_per_unit=force_per_unit,
    )


@pytest.mark.parametrize(
    ("effect", "model", "truth", "weights", "slot", "value"),
    [
        # weights: what the ranking would find on the truth's residual against itself (none),
        # or the weight an edit that sets the value from it needs to land on the truth
        ("coulomb_friction", EMPS, {"F_c_N": 15.0}, {}, "friction.F_c", 15.0),
        ("constant_force", EMPS, {"f_0_N": -20.0}, {"one": 20.0}, "constant_force.f_0", -20.0),
        ("backlash", AXIS, {"gap_m": 1e-5}, {}, "backlash.gap", 1e-5),
        (
            "thermal_drift",
            AXIS,
            {"heating_K_m": 2.0},
            {"x_D": -2.0 * ALPHA},
            "thermal.heating",
            2.0,
        ),
        ("channel_delay", EMPS, {"delay_s": 0.003}, {}, "analysis.effort_delay_s", 0.003),
        ("friction_drift", AXIS, {"rate_per_s": 0.02}, {}, "guides.drift_per_s", 0.02),
    ],
)
def test_a_truth_sets_what_the_edit_of_the_same_effect_fits(
    effect, model, truth, weights, slot, value
):
    """The synthetic truth and the workflow's edit go through the same component: the edit of
    the truth model frees the very slot the truth set, at the truth's value."""
    nominal = ModelDoc.load(model)
    hidden = model_of(BY_NAME[effect].truth(nominal, truth))
    edit = BY_NAME[effect].edit(hidden, _weights(effect, **weights))
    assert slot in {p.name for p in edit.own}
    assert model_of(edit.doc).get(slot) == pytest.approx(value, rel=1e-12)


def test_force_weights_of_a_current_record_enter_the_model_as_newtons():
    """On a PMSM axis the effort is a q-current: the ranking's weight of sign(v) is in amperes
    and 1 A is K_t 2 pi eta / lead = 1.9002 * 2 pi * 0.9 / 0.01 = 1075 N of friction at the
    table. Taken as newtons, the Coulomb edit started 40 N of missing friction at +0.03 N."""
    nominal = ModelDoc.load(AXIS)
    per_amp = nominal.force_per_effort("A")
    assert per_amp is not None, "the axis model has a screw and a motor"
    assert per_amp == pytest.approx(1.9002 * 2.0 * math.pi * 0.9 / 0.01, rel=1e-12)
    edit = BY_NAME["coulomb_friction"].edit(
        nominal, _weights("coulomb_friction", per_amp, sign_v=40.0 / per_amp)
    )
    assert model_of(edit.doc).get("guides.F_c") == pytest.approx(120.0 + 40.0, rel=1e-12)
    assert ModelDoc.load(EMPS).force_per_effort("N") == 1.0  # a force record


def test_a_friction_drift_starts_from_the_ranking_and_needs_a_friction():
    """A friction F_0 (1 + r t) that the model holds at its mean over the record, F_0 (1 + r
    t_mid), leaves F_0 r (t - t_mid) sign(v): F_0 = 120 N, r = 0.02 1/s, t_mid = 5 s (the
    variant the ranking carries) is a weight of 2.4 N/s with the model at 132 N, and the edit
    starts the rate at 2.4 / (132 - 2.4 * 5) = 0.02 1/s. Guides without friction cannot drift."""
    nominal = ModelDoc.load(AXIS)
    held = nominal.set("guides.F_c_pos", 132.0).set("guides.F_c_neg", 132.0)
    weights = dataclasses.replace(
        _weights("friction_drift", t_sign_v=2.4, t_v=0.0), variant="t_mid = 5 s"
    )
    edit = BY_NAME["friction_drift"].edit(held, weights)
    assert [p.name for p in edit.own] == ["guides.drift_per_s"]
    assert model_of(edit.doc).get("guides.drift_per_s") == pytest.approx(0.02, rel=1e-12)
    bare = nominal
    for name in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg", "dF_s"):
        bare = bare.set(f"guides.{name}", 0.0)
    with pytest.raises(LookupError, match="the model has no guide friction to drift"):
        BY_NAME["friction_drift"].edit(bare, weights)
