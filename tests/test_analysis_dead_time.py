"""dead_time: the inverter's interlock time, found in the voltage the current controller commands.

The machine-tool axis (config/axis_default.yaml: 560 V bus, 16 kHz PWM, 1 us nominal dead time
with the controller's compensation tuned for it) runs the long program of the stiffness tests;
the truth's inverter has a longer dead time than the compensation assumes.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.effects import motion_from_position as motion_of
from feed_twin.analysis.ranking import Candidate, rank
from feed_twin.analysis.synthetic import generate, write_csv
from feed_twin.analysis.twin import Drive, ModelDoc, Twin
from feed_twin.io.measured import load_measured
from feed_twin.plant.inverter import dead_time_voltage, leg_duty

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
# the long program and machine-tool NC of the stiffness tests: moves over most of the travel
LONG_PROGRAM = (ROOT / "tests" / "fixtures" / "analysis" / "long_travel.ngc").read_text()
TRUTH_T_DEAD_S = 2.0e-6  # the compensation assumes the nominal 1 us
dead_time = BY_NAME["dead_time"].edit  # the Inverter's edit of its own dead time


def _candidate(domain: str, coefficients: dict[str, float]) -> Candidate:
    return Candidate(
        effect=BY_NAME["dead_time"],
        variant="i_reg = 0.5 A",
        explained_fraction=0.9,
        f_statistic=1e4,
        p_value=0.0,
        n_eff=1000.0,
        coefficients=coefficients,
        significant=True,
        domain=domain,
    )


def _park(u_a: np.ndarray, u_b: np.ndarray, u_c: np.ndarray, theta: np.ndarray):
    alpha = (2.0 / 3.0) * (u_a - 0.5 * (u_b + u_c))
    beta = (u_b - u_c) / math.sqrt(3.0)
    return (
        np.cos(theta) * alpha + np.sin(theta) * beta,
        -np.sin(theta) * alpha + np.cos(theta) * beta,
    )


def test_saturated_signature_is_4_over_pi_along_q_with_a_sixth_harmonic_ripple():
    theta = np.linspace(0.0, 2.0 * math.pi * 20, 20 * 720, endpoint=False)
    shape = dead_time_voltage(np.full_like(theta, 50.0), theta, 1e-6)
    # the fundamental of a unit square wave is 4/pi; Clarke/Park keep a balanced amplitude
    assert np.mean(shape["q"]) == pytest.approx(4.0 / math.pi, rel=1e-3)
    assert np.mean(shape["d"]) == pytest.approx(0.0, abs=1e-6)
    spectrum = np.abs(np.fft.rfft(shape["q"] - shape["q"].mean()))
    per_revolution = np.arange(len(spectrum)) / 20.0  # harmonic order per electrical rev
    assert per_revolution[int(np.argmax(spectrum))] == pytest.approx(6.0)
    # negative current: the same shape with the opposite sign
    flipped = dead_time_voltage(np.full_like(theta, -50.0), theta, 1e-6)
    np.testing.assert_allclose(flipped["q"], -shape["q"], atol=1e-12)


def test_small_currents_give_a_voltage_proportional_to_i_q():
    """Below the PWM ripple the smooth sign is linear: the inverter looks like a resistance."""
    theta = np.linspace(0.0, 2.0 * math.pi, 360)
    i_q = np.full_like(theta, 1e-4)
    shape = dead_time_voltage(i_q, theta, 0.5)
    np.testing.assert_allclose(shape["q"], i_q / 0.5, rtol=1e-7)
    np.testing.assert_allclose(shape["d"], 0.0, atol=1e-10)


def test_signature_times_bus_voltage_and_dead_fraction_is_the_averaged_inverters_error():
    """Cross-check with the plant: three legs of feed_twin.plant.inverter, Park-transformed."""
    u_dc, fraction, i_reg = 560.0, 1.6e-2, 0.5
    rng = np.random.default_rng(1)
    theta = rng.uniform(0.0, 2.0 * math.pi, 200)
    i_q = rng.uniform(-3.0, 3.0, 200)
    i_a = -np.sin(theta) * i_q
    i_b = -np.sin(theta - 2.0 * math.pi / 3.0) * i_q
    i_c = -np.sin(theta + 2.0 * math.pi / 3.0) * i_q
    loss = []
    for currents in (i_a, i_b, i_c):
        # pole voltage lost to the dead time: (commanded - effective duty) * u_dc
        d_eff = np.array([leg_duty(0.5, i, fraction, i_reg, 1.0)[0] for i in currents])
        loss.append((0.5 - d_eff) * u_dc)
    loss_a, loss_b, loss_c = loss
    d_loss, q_loss = _park(loss_a, loss_b, loss_c, theta)
    shape = dead_time_voltage(i_q, theta, i_reg)
    np.testing.assert_allclose(q_loss, u_dc * fraction * shape["q"], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(d_loss, u_dc * fraction * shape["d"], rtol=1e-9, atol=1e-9)


def test_dead_fraction_is_a_document_slot_stored_as_t_dead():
    doc = ModelDoc.load(AXIS)
    assert doc.has_slot("inverter.dead_fraction")
    assert doc.get("inverter.dead_fraction") == pytest.approx(1e-6 * 16000.0, rel=1e-12)
    longer = doc.set("inverter.dead_fraction", 0.032)
    assert longer.component("inverter")["params"]["t_dead"] == pytest.approx(2e-6, rel=1e-12)
    assert doc.component("inverter")["params"]["t_dead"] == 1e-6  # the original is untouched
    twin = Twin.compile(longer)
    assert twin.nominal[twin.index["inverter.dead_fraction"][0]] == pytest.approx(0.032)


def test_edit_guesses_the_dead_time_from_the_voltage_weight():
    """Weight c [V] = u_dc * Delta t_dead * f_pwm: 8.96 V at 560 V and 16 kHz is 1 us more."""
    doc = ModelDoc.load(AXIS)
    edit = dead_time(doc, _candidate("voltage", {"sgn_i_q": 8.96}))
    (param,) = edit.own
    assert param.name == "inverter.dead_fraction"
    assert param.initial == pytest.approx(2e-6 * 16000.0, rel=1e-9)
    assert edit.doc.component("inverter")["params"]["t_dead"] == pytest.approx(2e-6, rel=1e-9)
    assert edit.report["t_dead_s"]({"inverter.dead_fraction": 0.048}) == pytest.approx(3e-6)
    assert edit.free == edit.own and edit.added == 1
    # an effort-domain weight is in amperes: the fit starts at the nominal dead time
    from_effort = dead_time(doc, _candidate("effort", {"sgn_i_q": 0.08}))
    assert from_effort.own[0].initial == pytest.approx(1e-6 * 16000.0, rel=1e-12)


def test_edit_fits_t_dead_itself_for_a_switching_inverter():
    doc = ModelDoc.load(AXIS)
    doc = doc.set_raw("inverter", "model", "switching")
    edit = dead_time(doc, _candidate("voltage", {"sgn_i_q": 8.96}))
    assert edit.own[0].name == "inverter.t_dead"
    assert edit.own[0].initial == pytest.approx(2e-6, rel=1e-9)
    assert edit.report["t_dead_s"]({"inverter.t_dead": 3e-6}) == 3e-6


def test_edit_needs_an_inverter():
    doc = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    with pytest.raises(LookupError, match="no Inverter whose dead time could be fitted"):
        dead_time(doc, _candidate("voltage", {"sgn_i_q": 1.0}))


def _synthetic_motion(with_current: bool = True):
    h = 1e-3
    t = h * np.arange(8000, dtype=np.float64)
    x = 0.1 + 0.08 * np.sin(2.0 * math.pi * 0.3 * t)
    a = -0.08 * (2.0 * math.pi * 0.3) ** 2 * np.sin(2.0 * math.pi * 0.3 * t)
    i_q = 0.4 * a + 0.2 * np.cos(2.0 * math.pi * 0.3 * t)
    motion = motion_of(
        t,
        x,
        effort_sim=i_q,
        lead_m=0.01,
        pole_pairs=4,
        travel_m=0.2,
        current_q_A=i_q if with_current else None,
    )
    return motion, i_q


def test_voltage_residual_names_dead_time_with_its_volts():
    motion, i_q = _synthetic_motion()
    theta_e = 4 * 2.0 * math.pi * motion.x_m / 0.01
    truth = 9.0 * dead_time_voltage(i_q, theta_e, 0.5)["q"]
    noise = np.random.default_rng(2).normal(0.0, 1.0, len(i_q))
    ranked = rank(
        motion,
        effort_residual=np.random.default_rng(3).normal(0.0, 0.01, len(i_q)),
        position_residual=None,
        voltage_residual=truth + noise,
    )
    top = ranked[0]
    assert top.name == "dead_time" and top.significant, [(c.name, c.p_value) for c in ranked]
    assert top.residual_domain == "voltage" and top.variant == "i_reg = 0.5 A"
    assert top.coefficients["sgn_i_q"] == pytest.approx(9.0, rel=0.02)


def test_without_voltage_dead_time_falls_back_to_the_effort():
    motion, _ = _synthetic_motion()
    ranked = rank(motion, effort_residual=motion.v_m_s, position_residual=None)
    found = {c.name: c for c in ranked}
    assert found["dead_time"].residual_domain == "effort"
    # and without a q-current the signature cannot be formed at all
    bare, _ = _synthetic_motion(with_current=False)
    ranked = rank(bare, effort_residual=bare.v_m_s, position_residual=None)
    assert "dead_time" not in [c.name for c in ranked]


@pytest.mark.slow
def test_twin_records_the_commanded_q_voltage_of_a_constant_speed_move():
    """At constant speed u_q = R_s i_q + omega_e psi_pm (the compensation cancels the nominal
    dead time): the back-EMF dominates, 4 * 2 pi * 0.1 / 0.01 rad/s * 0.3167 V s = 79.6 V."""
    twin = Twin.compile(ModelDoc.load(AXIS))
    h, v = 1e-3, 0.1
    t = h * np.arange(1500)
    x = 0.3 + v * t
    drive = Drive(
        t_s=t,
        pos_ref_m=x,
        vel_ref_m_s=np.full_like(t, v),
        acc_ref_m_s2=np.zeros_like(t),
        effort_add=None,
        force_ext_N=None,
        x0_m=0.3,
        sensor="linear_scale",
    )
    out = twin.simulate(drive, twin.nominal[None, :])
    assert out.ok[0] and out.voltage_q is not None and out.effort is not None
    steady = slice(1000, 1500)
    i_q = float(np.mean(out.effort[0, steady]))
    omega_e = 4 * 2.0 * math.pi * v / 0.01
    expected = 0.35 * i_q + omega_e * 0.3167
    assert float(np.mean(out.voltage_q[0, steady])) == pytest.approx(expected, rel=0.01)


def test_voltage_columns_need_no_drive_gain(tmp_path):
    t = np.arange(400) * 1e-3
    table = np.column_stack([t, 0.1 * t, 0.1 * t, 0.2 + 0.1 * t, 50.0 + t])
    np.savetxt(tmp_path / "run.csv", table, delimiter=",", header="t,xc,x,iq,uq", comments="")
    (tmp_path / "map.yaml").write_text(
        "time: {column: t, unit: s}\nposition_sensor: linear_scale\nsignals:\n"
        "  pos_cmd_m: {column: xc, unit: m}\n  pos_meas_m: {column: x, unit: m}\n"
        "  current_q_A: {column: iq, unit: A}\n  voltage_q_V: {column: uq, unit: V}\n"
        "plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}\n"
    )
    run = load_measured(tmp_path / "run.csv", tmp_path / "map.yaml")
    np.testing.assert_allclose(run["voltage_q_V"], 50.0 + t)


@pytest.mark.slow
@pytest.mark.parametrize("voltage", [True, False], ids=["with_u_q", "effort_only"])
def test_hidden_dead_time_is_named_fitted_and_closes_the_gap(tmp_path, voltage):
    """About 6 s each. With the drive's u_q recorded the signature explains ~97 % of the voltage
    residual; from the effort alone (~12 %) it is still named first."""
    from feed_twin.analysis.synthetic import NC_CONFIG

    nc = NC_CONFIG.replace("a_max_m_s2: 0.8", "a_max_m_s2: 3.0").replace(
        "j_max_m_s3: 40.0", "j_max_m_s3: 100.0"
    )
    nominal = ModelDoc.load(AXIS)
    truth = {"t_dead_s": TRUTH_T_DEAD_S}
    columns = generate(nominal, {"dead_time": truth}, program=LONG_PROGRAM, nc_config=nc)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    if not voltage:
        map_path.write_text(map_path.read_text().replace("  voltage_q_V", "  # voltage_q_V"))
    run = load_measured(tmp_path / "run.csv", map_path)
    assert ("voltage_q_V" in run) == voltage
    d, final, motion = diagnose(run, nominal)
    assert d.effects and d.effects[0].name == "dead_time", (d.notes, d.ranking[:3])
    assert d.effects[0].parameters["t_dead_s"] == pytest.approx(TRUTH_T_DEAD_S, rel=0.10)
    assert d.after.fe_dev_rms_m <= 0.2 * d.before.fe_dev_rms_m
    if voltage:
        after, before = d.after.voltage_q_rms_V, d.before.voltage_q_rms_V
        assert after is not None and before is not None, "a record with its voltage: its RMS"
        assert after <= 0.3 * before
        # `feed-twin simulate` writes the twin's voltage beside the measured one
        from feed_twin.analysis.cli import simulate_traces

        traces = simulate_traces(run, final)
        du = traces["voltage_q_V"] - traces["sim_voltage_q_V"]
        assert float(np.sqrt(np.mean(du**2))) == pytest.approx(d.after.voltage_q_rms_V, rel=1e-6)
        # the report shows the voltage residual before and after
        from feed_twin.analysis.report_files import write_report

        write_report(d, tmp_path / "out", v_m_s=motion.v_m_s)
        text = (tmp_path / "out" / "report.md").read_text()
        assert "| u_q residual RMS [V] |" in text
        assert f"| {d.before.voltage_q_rms_V:.4g} |" in text
        assert f"| {d.after.voltage_q_rms_V:.4g} |" in text
        assert (tmp_path / "out" / "identification.png").stat().st_size > 10_000
    else:
        assert d.after.voltage_q_rms_V is None
    # the fitted model carries it as the inverter's dead time, with the compensation unchanged
    fitted = final.component("inverter")["params"]["t_dead"]
    assert fitted == pytest.approx(d.effects[0].parameters["t_dead_s"], rel=1e-9)
    current = final.data["controller"]["current"]
    assert current["dead_time_comp_V"] == nominal.data["controller"]["current"]["dead_time_comp_V"]


def test_candidate_domain_defaults_to_the_effects_own():
    cand = dataclasses.replace(_candidate("voltage", {}), domain="")
    assert cand.residual_domain == "voltage"


def test_metrics_report_the_q_voltage_residual_rms():
    from feed_twin.analysis.compare import compute_metrics

    x = np.linspace(0.0, 0.1, 500)
    u = 40.0 * np.sin(np.linspace(0.0, 6.0, 500))
    m = compute_metrics(x, x, voltage_meas=u + 3.0, voltage_sim=u)
    assert m.voltage_q_rms_V == pytest.approx(3.0, rel=1e-12)
    assert compute_metrics(x, x).voltage_q_rms_V is None
