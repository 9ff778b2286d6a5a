"""The drive's electrical stage written into a torque-source twin (analysis.drive_stage): the
document it writes, the current loop's answer to a voltage error against its closed form, the
averaged dead-time law in the expanded twin against its mean over an electrical revolution, and
the dead time named on a truth-machine record."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.drive_stage import (
    MAX_DEAD_FRACTION,
    current_answer,
    drive_stage,
    expand,
    expandable,
    expanded,
)
from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.core.config import ConfigError

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "truth_nominal.yaml"
SEED = 7  # the benchmarks use 101-103


def _nominal() -> ModelDoc:
    return ModelDoc.load(NOMINAL)


def _with_stage(doc: ModelDoc, **changes: object) -> ModelDoc:
    data = copy.deepcopy(doc.data)
    data["analysis"]["drive_stage"].update(changes)
    return ModelDoc(data=data, source="m.yaml", reference_gain=doc.reference_gain)


def test_expand_writes_the_drive_stage_from_the_data_sheet() -> None:
    doc = _nominal()
    assert expandable(doc) and not expanded(doc)
    big = expand(doc)
    assert expanded(big) and not expandable(big)
    motor = big.component("drive")
    assert motor["type"] == "Pmsm"
    # K_t = 1.5 p psi_pm: the source's gain 0.45 N m/A with 3 pole pairs
    assert motor["params"]["psi_pm"] == pytest.approx(0.45 / (1.5 * 3))
    assert (motor["params"]["R_s"], motor["params"]["L_q"]) == (0.6, 2.5e-3)
    assert big.of_type("Inverter") == ["drive_inverter"]
    assert big.get("drive_inverter.t_dead") == 0.0
    assert big.get("drive_bus.u_0") == 300.0
    ctrl = big.data["controller"]
    assert ctrl["base_period_s"] == ctrl["current"]["period_s"] == 1.25e-4
    assert ctrl["computation_delay"] is True
    assert (ctrl["current"]["Kp_q_V_A"], ctrl["current"]["Ti_q_s"]) == (9.4, 4.2e-3)
    assert not ctrl["current"]["back_emf_ff"] and not ctrl["current"]["decoupling"]
    # the velocity and position loops keep their own periods
    assert ctrl["velocity"]["period_s"] == 2.5e-4 and ctrl["position"]["period_s"] == 5e-4
    # the record's effort was converted with the source's gain: the expanded twin's too
    assert big.reference_gain == pytest.approx(0.45)
    # the stiffest dead time the fit may reach (u_dc 0.02 / i_reg, 3/2 of it in the rotor
    # frame: 90 ohm on 2.5 mH) takes 2 RK4 steps per 125 us tick: h * 36 000 1/s = 2.3
    assert big.data["engine"]["substeps"] == 2
    assert expand(_with_stage(doc, i_reg_A=0.05)).data["engine"]["substeps"] == 4
    assert doc.of_type("EffortSource") == ["drive"]  # the nominal document is untouched


def _dead_time_edit(share: float, weight: float):
    """The dead time's edit on the nominal, ranked on the effort at `share` with `weight`."""
    from feed_twin.analysis.ranking import Candidate

    cand = Candidate(
        effect=BY_NAME["dead_time"],
        variant="i_reg = 0.1 A",
        explained_fraction=share,
        f_statistic=100.0,
        p_value=0.0,
        n_eff=1000.0,
        coefficients={"sgn_i_q": weight},
        significant=True,
        domain="effort",
    )
    return BY_NAME["dead_time"].edit(_nominal(), cand)


def test_dead_time_edit_starts_halfway_and_bounds_the_fit() -> None:
    edit = _dead_time_edit(0.3, 0.1)
    (own,) = edit.own
    assert own.name == "drive_inverter.dead_fraction"
    assert own.upper == MAX_DEAD_FRACTION
    assert edit.restructures  # tested against the stage at t_dead = 0 (analysis.rounds)
    assert own.initial == pytest.approx(0.5 * MAX_DEAD_FRACTION)
    assert edit.doc.get("drive_inverter.dead_fraction") == pytest.approx(own.initial)
    # reported in seconds: the fraction over the PWM frequency
    assert edit.report["t_dead_s"]({own.name: 0.008}) == pytest.approx(1e-6)
    truth = BY_NAME["dead_time"].truth(_nominal(), {"t_dead_s": 1.5e-6})
    assert truth.get("drive_inverter.t_dead") == pytest.approx(1.5e-6)


def test_current_answer_is_the_closed_loop_response_to_a_voltage_step() -> None:
    """A voltage step d on the windings: i(s) = d / (L s^2 + (R + Kp) s + Kp/Ti), two real
    poles r1, r2 at these gains, i(t) = d (e^(r1 t) - e^(r2 t)) / (L (r1 - r2))."""
    stage = drive_stage(_nominal())
    assert stage is not None
    t = np.arange(0.0, 0.03, 1e-4)
    d = 5.0
    answer = current_answer(stage, t)
    i = answer(np.full_like(t, d))
    # asked again for the same voltages (every ranking of a diagnosis asks for the same
    # signature), the answer is the one computed before, read-only, and not another's
    assert answer(np.full_like(t, d)) is i and not i.flags.writeable
    assert np.allclose(answer(np.full_like(t, 2.0 * d)), 2.0 * i)
    L, a, b = stage.L_H, stage.R_s_ohm + stage.Kp_V_A, stage.Kp_V_A / stage.Ti_s
    r1, r2 = np.roots([L, a, b])
    expected = d * (np.exp(r1 * t) - np.exp(r2 * t)) / (L * (r1 - r2))
    assert np.max(np.abs(i - expected)) < 2e-3 * np.max(np.abs(expected))
    # the dip: below d / (R + Kp) (the integrator acts while it rises), gone after a few
    # Ti (R + Kp) / Kp
    assert 0.8 * d / a < np.max(i) < d / a
    assert i[-1] < 0.01 * np.max(i)


def test_drive_stage_errors_name_the_field() -> None:
    doc = _nominal()
    with pytest.raises(ConfigError, match=r"drive_stage\.L_H = -1.0: must be > 0"):
        drive_stage(_with_stage(doc, L_H=-1.0))
    with pytest.raises(ConfigError, match=r"unknown key\(s\) R_ohm"):
        drive_stage(_with_stage(doc, R_ohm=1.0))
    data = copy.deepcopy(doc.data)
    del data["analysis"]["pole_pairs"]
    with pytest.raises(LookupError, match="pole_pairs = None: the motor's pole pairs are needed"):
        expand(ModelDoc(data=data, source="m.yaml"))
    data = copy.deepcopy(doc.data)
    del data["analysis"]["drive_stage"]
    bare = ModelDoc(data=data, source="m.yaml")
    assert not expandable(bare)
    with pytest.raises(LookupError, match="no single EffortSource with the drive's data sheet"):
        expand(bare)


@pytest.mark.slow
def test_expanded_twin_commands_the_dead_times_mean_volts(tmp_path: Path) -> None:
    """At constant speed the current loop's integrator makes up the mean voltage the dead
    time eats: u_dc t_dead f_pwm times the mean over an electrical revolution of the q part of
    the three phases' smooth signs (plant.inverter.dead_time_voltage), close to 4/pi for a
    current well above i_reg. Slow: it compiles the expanded twin's kernel (about 35 s, then
    cached), which the test below shares."""
    from feed_twin.analysis.twin import Drive, Twin
    from feed_twin.plant.inverter import dead_time_voltage

    del tmp_path
    twin = Twin.compile(expand(_nominal()))
    h = 1e-3
    t = np.arange(0.0, 0.7, h)
    v_max, ramp = 0.1, 0.1  # [m/s], [s]
    vel = v_max * np.clip(t / ramp, 0.0, 1.0)
    pos = 0.2 + np.concatenate(([0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * h)))
    drive = Drive(
        t_s=t,
        pos_ref_m=pos,
        vel_ref_m_s=vel,
        acc_ref_m_s2=np.gradient(vel, h),
        effort_add=None,
        force_ext_N=None,
        x0_m=0.2,
        sensor="motor_encoder",
    )
    t_dead, f_pwm, u_dc = 2e-6, 8000.0, 300.0
    slot = twin.plant.param_index["drive_inverter.dead_fraction"]
    rows = np.repeat(twin.nominal[None, :], 2, axis=0)
    rows[1, slot] = t_dead * f_pwm
    out = twin.simulate(drive, rows)
    assert out.ok.all() and out.voltage_q is not None and out.effort is not None
    # whole electrical periods at constant speed: 3 pole pairs, 10 mm lead, 0.1 m/s: 30 Hz
    window = (t >= 0.3) & (t < 0.3 + 9 / 30.0)
    gained = float(np.mean(out.voltage_q[1, window] - out.voltage_q[0, window]))
    i_q = float(np.mean(out.effort[1, window])) / 0.45
    theta = np.linspace(0.0, 2.0 * math.pi, 3601)[:-1]
    law = dead_time_voltage(np.full_like(theta, i_q), theta, 0.1)["q"]
    expected = u_dc * t_dead * f_pwm * float(np.mean(law))
    assert gained == pytest.approx(expected, rel=0.03)
    assert gained == pytest.approx(4.0 / math.pi * u_dc * t_dead * f_pwm, rel=0.15)


@pytest.mark.slow
def test_diagnose_names_the_dead_time_of_a_truth_record(tmp_path: Path) -> None:
    """The truth machine's inverter with a dead time (seed 7, which the benchmarks do not
    use), its current recorded as a torque, against the torque-source twin with the drive's
    data sheet: dead_time named first, within 5 %."""
    from feed_twin.analysis.diagnose import diagnose
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import draw_all, make_record

    hidden = draw_all(["dead_time"], seed=SEED)
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=SEED)
    d = diagnose(load_measured(rec.csv, rec.map), _nominal())[0]
    assert [e.name for e in d.effects][:1] == ["dead_time"], d.verdict
    found = d.effects[0].parameters["t_dead_s"]
    assert found == pytest.approx(hidden["dead_time"]["t_dead_s"], rel=0.05)


class _LineTwin:
    """A stand-in for a compiled twin with one parameter: its position is the parameter times
    t, so the cost against a record of `truth` times t is (value - truth)^2 times sum t^2."""

    def __init__(self, name: str, start: float) -> None:
        self.nominal = np.array([start])
        self.index = {name: (0,)}
        self.t = np.linspace(0.0, 1.0, 101)
        self.rows = 0

    def simulate(self, drive: object, params: np.ndarray):
        from feed_twin.analysis.fit import SimOutputs

        self.rows += len(params)
        x = params[:, :1] * self.t[None, :]
        return SimOutputs(x_m=x, effort=None, ok=np.ones(len(params), dtype=bool))


def test_a_new_stage_whose_cost_rises_from_its_lower_bound_is_not_fitted_further() -> None:
    """On a clean record the dead time's cost falls to its bound t_dead = 0 and the least
    squares took 24 simulations of the expanded twin to get there: two (the bound and
    BOUND_STEP inside it) say the optimum lies at the values without it. Where the cost falls
    inward, or for an edit that writes no new stage, the least squares runs (None)."""
    import dataclasses

    from feed_twin.analysis.fit import Measured
    from feed_twin.analysis.trials import BOUND_STEP, optimum_at_bound

    edit = _dead_time_edit(0.06, 1.47)  # a clean truth record's ranking
    (own,) = edit.own
    assert own.lower == 0.0  # the stage without a dead time: what the trial is tested against

    def tried(truth: float, e=edit):
        twin = _LineTwin(own.name, own.initial)
        meas = Measured(x_m=truth * twin.t, effort=None, scale_x=1e-3, scale_effort=1.0)
        return optimum_at_bound(twin, None, e, [own], meas), twin  # pyright: ignore[reportArgumentType]

    at_bound, twin = tried(0.0)
    assert at_bound is not None and twin.rows == 2 and at_bound.evaluations == 2
    assert at_bound.values == {own.name: 0.0} and at_bound.converged
    assert at_bound.cost == at_bound.cost_initial == pytest.approx(0.0)
    assert at_bound.message == f"the cost rises from {own.name}'s lower bound 0 inward"
    # a dead time a fifth of the way from the bound to BOUND_STEP: the cost still rises there
    assert tried(0.2 * BOUND_STEP * own.scale)[0] is not None
    # beyond half the step the cost falls inward: fitted by least squares
    assert tried(0.6 * BOUND_STEP * own.scale)[0] is None
    assert tried(own.initial)[0] is None
    assert tried(0.0, dataclasses.replace(edit, restructures=False))[0] is None
