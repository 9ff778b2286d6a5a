"""The model at a slow record's scale (analysis.record_scale): the 16 kHz axis reduced to its
mechanics and loops, checked against the full model on the 10 Hz mill log (two paths), and
what the reduction keeps and refuses."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.record_scale import EFFORT_AGREEMENT, agreement, at_record_scale, reduce
from feed_twin.analysis.recorder import period_mean, window_mean
from feed_twin.analysis.twin import Twin
from feed_twin.analysis.visibility import smooth_staircases
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import load_measured, segment

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
MILL = ROOT / "tests" / "fixtures" / "umich_mill"
Q = 1e-3  # [m] the mill log's X resolution


def _reduced() -> ModelDoc:
    doc, _ = reduce(ModelDoc.load(AXIS), resolution_m=Q)
    assert doc is not None
    return doc


def test_the_axis_reduces_to_its_mechanics_and_loops():
    full = ModelDoc.load(AXIS)
    doc = _reduced()
    kinds = {e["name"]: e["type"] for e in doc.data["plant"]["components"]}
    for gone in ("bus", "inverter", "current_sensor", "coupling", "backlash"):
        assert gone not in kinds
    assert kinds["motor"] == "Inertia" and kinds["screw_shaft"] == "Inertia"
    assert "axial" not in kinds and doc.get("screw.efficiency") == 1.0
    ctrl = doc.data["controller"]
    assert doc.base_period() == pytest.approx(1e-3)  # the NC's period
    assert "current" not in ctrl and ctrl["computation_delay"] is False
    # the velocity loop re-tuned for 1 ms (symmetric optimum, as the controller node's)
    assert ctrl["velocity"]["period_s"] == pytest.approx(1e-3)
    assert ctrl["velocity"]["Kp"] < full.data["controller"]["velocity"]["Kp"] / 5
    k_t, eta = 1.5 * 4 * 0.3167, 0.9  # 1.5 p psi_pm [N m/A]; the screw's efficiency
    # the screw's loss on the motor's side: torque and rotor inertias times eta
    assert doc.get("motor_torque.gain") == pytest.approx(k_t * eta)
    assert doc.get("motor.J") == pytest.approx(3.1e-3 * eta)
    # the screw shaft's inertia stays: rho pi d^4 L / 32
    assert doc.get("screw_shaft.J") == pytest.approx(eta * 7850 * math.pi * 0.04**4 / 32)
    # newtons at the table per ampere, as in the full model: K_t 2 pi eta / lead
    assert doc.force_per_effort("A") == pytest.approx(full.force_per_effort("A"))
    # the rotor's friction at the table, in the same current: T_c through the screw (2 pi eta /
    # lead), its viscous b plus the iron loss's K_t p psi_pm / R_fe per rad/s
    per_torque = 2 * math.pi * 0.9 / 0.01
    assert doc.get("motor_friction.F_c_pos") == pytest.approx(0.03 * per_torque)
    b = 2e-4 + k_t * 4 * 0.3167 / 1500.0
    assert doc.get("motor_friction.F_v_pos") == pytest.approx(b * 2 * math.pi / 0.01 * per_torque)
    twin = Twin.compile(doc)
    assert twin.effort_name == "current_q_A" and twin.effort_unit == "A"
    assert doc.friction() == "guides"  # the effects still edit the guides


def test_a_model_at_its_scale_is_not_reduced():
    doc, why = reduce(ModelDoc.load(MILL / "mill_nominal.yaml"), resolution_m=Q)
    assert doc is None and why == ["the model runs at its NC period already"]


def test_a_wide_backlash_stays():
    full = ModelDoc.load(AXIS).set("backlash.gap", 2e-3)
    doc, _ = reduce(full, resolution_m=Q)
    assert doc is not None and doc.of_type("Backlash") == ["backlash"]


def test_only_a_current_can_stand_for_an_effort_source_command():
    doc = ModelDoc.load(MILL / "mill_nominal.yaml")
    doc.data["analysis"] = {"effort_signal": "voltage_q_V"}
    with pytest.raises(ConfigError, match=r"analysis.effort_signal = 'voltage_q_V': the only"):
        doc.effort_signal()


def test_the_reduced_and_the_full_model_agree_on_the_mill_log():
    """Two paths: the 16 kHz axis with its PMSM, inverter, coupling and screw springs, and its
    reduction, driven by 20 s of the 10 Hz log's command. Where the command moves, the sample
    means of their efforts agree within EFFORT_AGREEMENT (2 %) of its RMS, their positions
    within half the log's 1 mm; the reduction is used and says so."""
    raw = load_measured(MILL / "experiment_01.csv", MILL / "x_map_axis.yaml")
    run, _ = smooth_staircases(segment(raw, 0.0, 20.0))
    full = ModelDoc.load(AXIS)
    agree = agreement(Twin.compile(full), Twin.compile(_reduced()), run, resolution_m=Q)
    assert agree.effort_share < EFFORT_AGREEMENT
    assert agree.position_max_m < 0.5 * Q
    doc, said = at_record_scale(run, full, resolution_m=Q)
    assert doc.of_type("Pmsm") == []
    (line,) = said
    assert line.startswith("model at the record's scale (what a 10 Hz record can show): step ")
    assert "checked on this record against the full model" in line


def test_a_reduction_that_disagrees_keeps_the_full_model():
    """A backlash of 0.5 mm is below the 1 mm resolution, so the reduction drops it; but the
    lost motion moves the table 0.25 mm off the rigid twin's at each reversal: the full model
    is kept and the line says why."""
    raw = load_measured(MILL / "experiment_01.csv", MILL / "x_map_axis.yaml")
    run, _ = smooth_staircases(segment(raw, 0.0, 20.0))
    full = ModelDoc.load(AXIS).set("backlash.gap", 5e-4)
    doc, said = at_record_scale(run, full, resolution_m=Q)
    assert doc is full
    (line,) = said
    assert line.startswith("the model at the record's scale does not agree with the full one")
    assert line.endswith("the full model is simulated")


def test_a_drive_trace_keeps_its_model(tmp_path):
    """A 1 kHz trace can show what the reduction drops: nothing is reduced or simulated."""
    t = np.arange(0.0, 1.0, 1e-3)
    x = 0.4 + 0.01 * t
    rows = "\n".join(f"{a:.3f},{b:.6f},{b:.6f},{0.1 + a:.3f}" for a, b in zip(t, x, strict=True))
    (tmp_path / "run.csv").write_text("t,cmd,act,iq\n" + rows + "\n")
    (tmp_path / "map.yaml").write_text(
        "time: {column: t, unit: s}\nposition_sensor: linear_scale\nsignals:\n"
        "  pos_cmd_m: {column: cmd, unit: m}\n  pos_meas_m: {column: act, unit: m}\n"
        "  current_q_A: {column: iq, unit: A}\nplausibility: {travel_m: 1.0, max_speed_m_s: 0.5}\n"
    )
    run = load_measured(tmp_path / "run.csv", tmp_path / "map.yaml")
    full = ModelDoc.load(AXIS)
    assert at_record_scale(run, full, resolution_m=0.0) == (full, [])


def test_a_torque_source_axis_keeps_its_resolved_springs_gains_and_effort_gain():
    """The truth machine's nominal twin (an ideal torque source; velocity loop 4 kHz, position
    loop 2 kHz) at a 10 Hz record's scale: its loops step to the NC's 1 ms with the drive's
    own gains (within what the symmetric optimum allows at 1 ms: Kp 481.7, Ti 8 ms), its axial
    spring stays (the step resolves it in one RK4 step: rigid saved nothing and changed what
    was named) while its coupling, whose 1.1 kHz mode the step does not resolve, is rigid, and
    its effort converts as the full model's (the EffortSource's gain)."""
    full = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    doc, changes = reduce(full, resolution_m=1e-4)
    assert doc is not None
    assert changes == ["step 0.25 ms -> 1 ms (no current loop)", "coupling (Coupling) rigid"]
    assert doc.base_period() == pytest.approx(1e-3)
    assert "axial" in {e["name"] for e in doc.data["plant"]["components"]}
    velocity = doc.data["controller"]["velocity"]
    assert (velocity["Kp"], velocity["Ti_s"]) == (480.0, 0.016)
    assert doc.reference_gain == full.reference_gain == pytest.approx(0.45)


def test_period_means_of_a_ramp_are_its_mean_over_the_period_at_any_tick():
    """Analytic: a ramp y = y0 + b t sampled every h, its mean over the 100 ms ending at each
    sample is y0 + b (t - 50 ms) whatever h (the trapezoid rule is exact on a line); the mean
    of the dec ticks ending there lies b h / 2 later, which differed between the 0.25 ms and
    the 1 ms twin of one axis by 0.375 ms (56 um at 150 mm/s)."""
    period, b = 0.1, 0.15  # [s], [m/s]
    for h in (2.5e-4, 1e-3):
        dec = round(period / h)
        t = h * np.arange(10 * dec)
        y = 0.2 + b * t
        ends = t[::dec][1:]
        assert period_mean(y, dec)[0, 1:] == pytest.approx(0.2 + b * (ends - 0.5 * period))
        assert period_mean(y, dec)[0, 0] == pytest.approx(0.2)
        late = window_mean(y, dec)[0, 1:] - (0.2 + b * (ends - 0.5 * period))
        assert late == pytest.approx(np.full(len(ends), 0.5 * b * h))


def test_the_truth_twin_and_its_reduction_agree_on_a_10_hz_log(tmp_path):
    """Two paths on the truth machine's 10 Hz log of a shop-floor program's moves (up to
    150 mm/s): the 0.25 ms nominal twin and its 1 ms reduction, whose period means lay 57 um
    apart (the means' half-tick offset) and were refused at 0.1 mm. Compared over the same
    time they agree within a tenth of the 50 um limit, and the reduction is used."""
    from feed_twin.truth import Trace, make_record

    moves = "G1 X150 F9000\nG4 P0.8\nG1 X20 F4800\nG4 P0.8\nG1 X200 F9000\nG4 P0.8\n"
    program = f"G21 G90 G94 G54 G64\nG1 X0 F3000\n{moves}G1 X60 F1200\nG4 P8\nM30\n"
    trace = Trace(period_s=0.1, position_resolution_m=1e-4, command_resolution_m=1e-4)
    rec = make_record(tmp_path / "log.csv", trace=trace, program=program, seed=11)
    run = load_measured(rec.csv, rec.map)
    full = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    small, _ = reduce(full, resolution_m=1e-4)
    assert small is not None
    agree = agreement(Twin.compile(full), Twin.compile(small), run, resolution_m=1e-4)
    assert agree.position_max_m < 5e-6
    doc, (line,) = at_record_scale(run, full, resolution_m=1e-4)
    assert doc.base_period() == pytest.approx(1e-3)
    assert line.startswith("model at the record's scale")
