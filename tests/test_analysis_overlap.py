"""The workflow, blind, on effects that overlap: both named, neither soaking up the other.

Each record is a synthetic run (analysis.synthetic: truth = twin + effects + current-loop lag +
a 3 % softer coupling + the encoder's true counts + effort noise) written as a CSV with its
column map; the workflow gets only those and the nominal model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from twin_support import assert_current_lag_taken_as_timing

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.reexamine import Found, collapsed, neutral_values
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.synthetic import NC_CONFIG, generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured
from feed_twin.plant.external_force import with_constant_force

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"
AXIS = ROOT / "config" / "axis_default.yaml"
LONG_PROGRAM = (ROOT / "tests" / "fixtures" / "analysis" / "long_travel.ngc").read_text()
MACHINE_TOOL_NC = NC_CONFIG.replace("a_max_m_s2: 0.8", "a_max_m_s2: 3.0").replace(
    "j_max_m_s3: 40.0", "j_max_m_s3: 100.0"
)


def _diagnose(tmp_path: Path, nominal: ModelDoc, hidden: dict, **kwargs):
    columns = generate(nominal, hidden, **kwargs)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    return diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]


def _found(d) -> dict[str, dict[str, float]]:
    return {e.name: e.parameters for e in d.effects}


def test_neutral_values_are_the_model_before_the_effect():
    before = ModelDoc.load(AXIS)
    fr = before.friction()
    after = before.tie(f"{fr}.F_c", (f"{fr}.F_c_pos", f"{fr}.F_c_neg")).set(f"{fr}.F_c", 160.0)
    after, slot = with_constant_force(after, -20.0)
    assert isinstance(after, ModelDoc), "the edit keeps the document's class"
    neutral = neutral_values(before, after, (f"{fr}.F_c", slot))
    # the tie did not exist before: its members' mean; the new component: zero
    assert neutral == {f"{fr}.F_c": 120.0, slot: 0.0}


def test_an_effect_whose_size_fell_back_to_neutral_has_collapsed():
    edited, slot = with_constant_force(ModelDoc.load(EMPS), -20.0)
    assert isinstance(edited, ModelDoc), "the edit keeps the document's class"
    doc = edited
    found = Found(
        effect=FoundEffect(
            name="constant_force", evidence="", parameters={}, explained_fraction=0.5, component=""
        ),
        own=(),
        neutral={slot: 0.0},
        at_discovery={slot: -20.0},
        report={},
        added=1,
    )
    assert not collapsed(found, doc)
    assert not collapsed(found, doc.set(slot, -2.5))  # 12.5 % of its size is still there
    assert collapsed(found, doc.set(slot, -1.5))


@pytest.mark.slow
def test_vertical_axis_keeps_the_weight_and_the_coulomb_friction(tmp_path):
    """The weight takes 98 % of the effort residual; the friction that is left halves what
    remains many times over and must not be judged by the position channel's noise."""
    hidden = {"constant_force": {"f_0_N": -150.0}, "coulomb_friction": {"F_c_N": 20.0}}
    d = _diagnose(tmp_path, ModelDoc.load(EMPS), hidden)
    found = _found(d)
    assert set(found) == set(hidden), d.notes
    assert found["constant_force"]["f_0_N"] == pytest.approx(-150.0, rel=0.02)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(20.0, rel=0.05)
    assert d.after.effort_rms is not None, "the record has an effort: its residual has an RMS"
    assert d.after.effort_rms < 0.6  # the effort noise is 0.3 N, the lag adds the rest


@pytest.mark.slow
def test_constant_force_and_asymmetric_friction_are_both_named(tmp_path):
    hidden = {
        "constant_force": {"f_0_N": -20.0},
        "asymmetric_friction": {"F_v_pos": 160.0, "F_v_neg": 250.0},
    }
    d = _diagnose(tmp_path, ModelDoc.load(EMPS), hidden)
    found = _found(d)
    assert set(found) == set(hidden), d.notes
    assert found["constant_force"]["f_0_N"] == pytest.approx(-20.0, rel=0.10)
    assert found["asymmetric_friction"]["F_v_pos"] == pytest.approx(160.0, rel=0.10)
    assert found["asymmetric_friction"]["F_v_neg"] == pytest.approx(250.0, rel=0.10)


@pytest.mark.slow
def test_clean_record_names_nothing(tmp_path):
    assert_current_lag_taken_as_timing(_diagnose(tmp_path, ModelDoc.load(EMPS), {}))


@pytest.mark.slow
def test_stiffness_and_coulomb_friction_are_both_named(tmp_path):
    """Machine-tool axis, loop on the linear scale: a softer screw and more Coulomb friction
    (160 N where the model has 120 N); about a minute. Before the edits started from the
    model's friction, a viscous term took the friction's place and collapsed in the joint
    re-fit, and the collapsed term stayed in the report."""
    truth = {"k_bearing_N_m": 4.0e8, "EA_N": 1.2e8}
    hidden = {"position_dependent_stiffness": truth, "coulomb_friction": {"F_c_N": 160.0}}
    d = _diagnose(
        tmp_path,
        ModelDoc.load(AXIS),
        hidden,
        program=LONG_PROGRAM,
        nc_config=MACHINE_TOOL_NC,
    )
    found = _found(d)
    assert set(found) == set(hidden), d.notes
    for name, value in truth.items():
        assert found["position_dependent_stiffness"][name] == pytest.approx(value, rel=0.10)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(160.0, rel=0.05)


@pytest.mark.slow
def test_backlash_and_coulomb_friction_are_both_named(tmp_path):
    """Semi-closed loop, the scale reads the table: 10 um of lost motion (2 um nominal) and
    160 N of Coulomb friction (120 N nominal). Behind the gap the friction decides whether the
    table slides across it while the nut decelerates (200 kg at 0.8 m/s^2 is 160 N): a cliff in
    the cost that a fit started from the nominal 120 N never saw. It stalled there while the
    Coulomb weight in amperes was taken as newtons (+0.03 N instead of +40 N), and a Stribeck
    term took its place; about five minutes on a loaded machine."""
    nominal = ModelDoc.load(AXIS)
    nominal.data["controller"]["position"]["feedback"] = "motor_encoder"
    hidden = {"backlash": {"gap_m": 10e-6}, "coulomb_friction": {"F_c_N": 160.0}}
    d = _diagnose(tmp_path, nominal, hidden, start_m=0.3)
    found = _found(d)
    assert set(found) == set(hidden), d.notes
    assert found["backlash"]["gap_m"] == pytest.approx(10e-6, rel=0.05)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(160.0, rel=0.05)


@pytest.mark.slow
def test_a_delay_between_recorded_channels_is_named_and_measured(tmp_path):
    """The recorder stamps the effort 3 ms after the position (trace side, not in the loop):
    named channel_delay with its size, not a sensor delay in the loop, which would move the
    following error too."""
    nominal = ModelDoc.load(EMPS)
    columns = generate(nominal, {"coulomb_friction": {"F_c_N": 15.0}})
    late = 3
    effort = columns["u_drive_V"]
    columns["u_drive_V"] = np.concatenate((np.full(late, effort[0]), effort[:-late]))
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    d = diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]
    found = _found(d)
    assert set(found) == {"coulomb_friction", "channel_delay"}, d.notes
    assert found["channel_delay"]["delay_s"] == pytest.approx(3e-3, abs=0.25e-3)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(15.0, rel=0.05)
