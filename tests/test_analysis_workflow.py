"""The workflow, blind, on synthetic runs with hidden effects (truth: twin + effect + lag + sensor).

The generator writes a CSV and a column map exactly as a user brings real data; the workflow
gets only those and the nominal model. Pass criteria from issue 6: the hidden effect is named
first, its parameters are within 10 % of the truth, and the RMS following-error deviation
shrinks by at least 80 %.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from twin_support import assert_current_lag_taken_as_timing

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.model_doc import model_of
from feed_twin.analysis.synthetic import HIDDEN, generate, position_spread, write_csv
from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import load_measured

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"

# effect -> (hidden truth parameters, the workflow's reported names for them)
CASES = {
    "coulomb_friction": {"F_c_N": 15.0},
    "viscous_friction": {"F_v_N_s_m": 300.0},
    "stribeck_friction": {"dF_s_N": 15.0, "v_s_m_s": 0.005},
    "asymmetric_friction": {"F_v_pos": 160.0, "F_v_neg": 250.0},
    "constant_force": {"f_0_N": -20.0},
    "mass_error": {"m_kg": 120.0},
    "torque_constant_error": {"gain": 29.88},
    "measurement_delay": {"delay_ticks": 2},
}


def _blind_run(tmp_path: Path, hidden: dict, seed: int = 0):
    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, hidden)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    return diagnose(run, nominal)[0]


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(CASES))
def test_hidden_effect_is_named_fitted_and_closes_the_gap(tmp_path, effect):
    truth = CASES[effect]
    d = _blind_run(tmp_path, {effect: truth})
    assert d.effects, d.notes
    first = d.effects[0]
    assert first.name == effect, [(e.name, e.parameters) for e in d.effects]
    for name, value in truth.items():
        assert first.parameters[name] == pytest.approx(value, rel=0.10), first.parameters
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m


@pytest.mark.slow
def test_effect_free_run_names_nothing(tmp_path):
    assert_current_lag_taken_as_timing(_blind_run(tmp_path, {}))


@pytest.mark.slow
def test_two_simultaneous_effects_are_both_named(tmp_path):
    hidden = {"coulomb_friction": {"F_c_N": 15.0}, "constant_force": {"f_0_N": -20.0}}
    d = _blind_run(tmp_path, hidden)
    names = [e.name for e in d.effects]
    assert set(names[:2]) == set(hidden), names
    found = {e.name: e.parameters for e in d.effects}
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(15.0, rel=0.10)
    assert found["constant_force"]["f_0_N"] == pytest.approx(-20.0, rel=0.10)
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m


# seeds of the cogging record's other realisations (the record itself is seed 0)
OTHER_REALISATIONS = (1, 2, 3)
REPRODUCIBLE_WINDOW_S = 0.1  # [s] windows over which the realisations' spread is judged
# a window is judged where the realisations' spread is at most this share of the deviation to
# remove there: half the 20 % the criterion allows, the rest is the fit's
REPRODUCIBLE_SHARE = 0.1


@pytest.mark.slow
def test_cogging_is_found_on_the_machine_tool_axis(tmp_path):
    """PMSM axis (16 kHz current loop, scale feedback): cogging is named, order and amplitude.

    0.6 N m is about 4 % of the motor's rated torque. The effect-free FE residual of this run is
    33 nm (sensor noise and quantisation through the loop); 0.3 N m of cogging adds only 161 nm
    RMS, so even a perfect fit could not remove 80 % of it.

    The gap is judged where the record is reproducible. This motion's reversals pass through
    zero speed while accelerating: the nut crosses its 2 um backlash and strikes, and the table
    comes to rest on its stiction at the end. There the truth's current ADC (steps of 24 mA,
    20 mA noise) decides when and how hard: records of the same machine that differ only in
    their noise seeds part by up to 1.3 um (39-70 nm RMS over the record), and changing only
    the truth's RK4 sub-steps moves its record by 24-77 nm RMS (0.1-1.2 nm with smooth
    sensors); the jerk filter's integral in two doubles (i30jerk) moved the command by rounding
    alone (5e-14 m) and took this fit's residual from 77 to 33 nm.
    The smooth twin at the TRUE cogging is one more such realisation: it leaves 23-98 nm over
    the record on 16 realisations, 70 nm on this one. So (1) in the 0.1 s windows whose spread
    is at most a tenth of the deviation to remove (71 of 82 here) the FE deviation shrinks by
    80 %, as in the other cases (the twin at the true values: 4-11 % left on 20 realisations),
    and (2) over the whole record the fit closes 80 % of what the twin at the true values
    closes.
    """
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    truth = {"order": 6, "amplitude_Nm": 0.6, "phase_rad": 0.5}
    columns = generate(nominal, {"cogging_torque": truth}, start_m=0.3)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    d = diagnose(run, nominal)[0]
    assert d.effects and d.effects[0].name == "cogging_torque", d.notes
    found = d.effects[0].parameters
    assert found["order"] == 6
    assert found["amplitude_Nm"] == pytest.approx(0.6, rel=0.10)
    assert found["phase_rad"] == pytest.approx(0.5, abs=0.1)
    spread = position_spread(
        nominal, {"cogging_torque": truth}, seeds=(0, *OTHER_REALISATIONS), start_m=0.3
    )
    x = run["pos_meas_m"]
    per = round(REPRODUCIBLE_WINDOW_S / run.sample_period_s)
    n = len(x) // per

    def windows(y: np.ndarray) -> np.ndarray:
        return np.sqrt(np.mean(y[: n * per].reshape(n, per) ** 2, axis=1))

    gap_before = windows(d.before_trace.x_sim_m - x)
    gap_after = windows(d.after_trace.x_sim_m - x)
    reproducible = windows(spread) <= REPRODUCIBLE_SHARE * gap_before
    assert reproducible.sum() >= 0.75 * n, windows(spread)  # the floor is local, not the record
    kept_before = np.sqrt(np.mean(gap_before[reproducible] ** 2))
    kept_after = np.sqrt(np.mean(gap_after[reproducible] ** 2))
    assert kept_after <= 0.2 * kept_before, (kept_before, kept_after)
    true_twin = Twin.compile(model_of(HIDDEN["cogging_torque"](nominal, truth)))
    x_true = true_twin.simulate(drive_from_run(run), true_twin.nominal[None, :]).x_m[0]
    floor = float(np.sqrt(np.mean((x_true - x) ** 2)))
    before, after = d.before.fe_dev_rms_m, d.after.fe_dev_rms_m
    assert after**2 - floor**2 <= 0.2**2 * (before**2 - floor**2), (before, after, floor)


@pytest.mark.slow
def test_position_only_record_still_names_a_missing_force(tmp_path):
    """A scope that logged no effort: the loop's stiffness turns the FE deviation into force."""
    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, {"constant_force": {"f_0_N": -20.0}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    map_path.write_text(map_path.read_text().replace("  force_cmd_N", "  # force_cmd_N"))
    run = load_measured(tmp_path / "run.csv", map_path)
    assert run.effort_name is None
    d = diagnose(run, nominal)[0]
    assert [e.name for e in d.effects][:1] == ["constant_force"], d.notes
    assert d.effects[0].parameters["f_0_N"] == pytest.approx(-20.0, rel=0.10)
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m


@pytest.mark.slow
def test_lead_error_is_found_by_the_linear_scale_of_a_semi_closed_loop(tmp_path):
    """Loop closed on the motor encoder, table read by the scale: the scale sees the pitch error."""
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    nominal.data["controller"]["position"]["feedback"] = "motor_encoder"
    truth = {"amplitude_m": 3e-6, "phase_rad": 0.7}
    columns = generate(nominal, {"lead_error": truth}, start_m=0.3)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    d = diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]
    assert d.effects and d.effects[0].name == "lead_error", d.notes
    found = d.effects[0].parameters
    assert found["amplitude_m"] == pytest.approx(3e-6, rel=0.10)
    assert found["phase_rad"] == pytest.approx(0.7, abs=0.1)
    assert found["period_m"] == pytest.approx(0.01)  # once per screw revolution
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m


@pytest.mark.slow
def test_fit_that_does_not_converge_says_so_and_keeps_the_last_good_model(tmp_path):
    from feed_twin.analysis.diagnose import Options

    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, {"coulomb_friction": {"F_c_N": 15.0}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    d, final, _ = diagnose(run, nominal, options=Options(max_evaluations=1))
    assert any("coulomb_friction did not converge" in n and "kept the last good model" in n
               for n in d.notes), d.notes  # fmt: skip
    assert "coulomb_friction" not in [e.name for e in d.effects]
    assert final.data == nominal.data  # nothing unconverged was adopted


@pytest.mark.slow
def test_thermal_drift_is_found_by_the_linear_scale_of_a_semi_closed_loop(tmp_path):
    """The screw warms as it travels and lengthens: a linear scale sees the table drift away."""
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    nominal.data["controller"]["position"]["feedback"] = "motor_encoder"
    truth = {"heating_K_m": 2.0}
    columns = generate(nominal, {"thermal_drift": truth}, start_m=0.3)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    d = diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]
    assert d.effects and d.effects[0].name == "thermal_drift", d.notes
    assert d.effects[0].parameters["heating_K_m"] == pytest.approx(2.0, rel=0.10)
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m


@pytest.mark.slow
def test_backlash_is_found_as_lost_motion_at_reversals(tmp_path):
    """Semi-closed loop: after each reversal the scale sees the table a half gap behind the nut."""
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    nominal.data["controller"]["position"]["feedback"] = "motor_encoder"
    columns = generate(nominal, {"backlash": {"gap_m": 10e-6}}, start_m=0.3)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    d = diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]
    assert d.effects and d.effects[0].name == "backlash", d.notes
    assert d.effects[0].parameters["gap_m"] == pytest.approx(10e-6, rel=0.10)
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m
