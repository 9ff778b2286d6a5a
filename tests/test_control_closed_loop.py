"""The controller closed around the compiled plant: designed behaviour against simulated.

Current step rise time against the tuning helper's design, velocity-loop bandwidth from a
simulated frequency response against the linearised design, and the following error of the P
position loop on a ramp (v/Kv) with and without velocity feed-forward.
"""

import copy
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.control.tuning import tune_config, tune_current_loop
from feed_twin.core import signals as sig
from feed_twin.core.config import load_yaml
from feed_twin.sim.config import build_engine, load_axis_config

AXIS_FILE = Path(__file__).resolve().parent.parent / "config" / "axis_default.yaml"
AXIS = load_axis_config(AXIS_FILE)
T = AXIS.controller.base_period_s


def _with_controller(axis, **changes):
    return dataclasses.replace(axis, controller=dataclasses.replace(axis.controller, **changes))


def test_current_step_reaches_90_percent_at_the_design_rise_time():
    cur = AXIS.controller.current
    design = tune_current_loop(R_s=cur.R_s_ohm, L=cur.L_q_H, period_s=cur.period_s)
    engine = build_engine(AXIS, mode="torque", output_period_s=T)
    step = 5.0
    n = 160  # 10 ms
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_I_Q_EXT_A] = step
    res = engine.run(n, ref=ref)
    i_q, t = res["motor.i_q"], res.t
    j = int(np.argmax(i_q >= 0.9 * step))
    t_90 = t[j - 1] + (0.9 * step - i_q[j - 1]) / (i_q[j] - i_q[j - 1]) * (t[j] - t[j - 1])
    assert t_90 == pytest.approx(design.rise_time_90_s, rel=0.2)
    # the integrator and the dead-time compensation leave no steady error (sensor noise 0.02 A)
    assert np.mean(i_q[t > 3e-3]) == pytest.approx(step, rel=0.01)
    assert np.all(np.abs(res["motor.i_d"][t > 3e-3]) < 0.1)


def _rigid_axis():
    """The axis's electrical drive on a rigid shaft carrying J_total: the plant the tuning
    rules assume, so the comparison tests the controller's discrete implementation."""
    raw = load_yaml(AXIS_FILE)
    parts = {c["name"]: c for c in raw["plant"]["components"]}
    motor = copy.deepcopy(parts["motor"])
    motor["params"]["J"] = raw["controller"]["drive"]["J_total_kg_m2"]
    rigid = dict(raw)
    rigid["plant"] = {
        "components": [
            parts["bus"],
            parts["inverter"],
            motor,
            parts["current_sensor"],
            parts["encoder"],
        ],
        "connect": [
            ["bus.dc", "inverter.dc"],
            ["inverter.ac", "motor.ac"],
            ["current_sensor.ac", "motor.ac"],
            ["motor.flange", "encoder.flange"],
        ],
    }
    rigid["controller"] = copy.deepcopy(raw["controller"])
    rigid["controller"]["position"]["feedback"] = "motor_encoder"
    return load_axis_config(rigid, source="rigid axis")


@pytest.mark.slow
def test_velocity_loop_bandwidth_from_simulated_frequency_response():
    axis = _rigid_axis()
    design_hz = tune_config(axis.controller).velocity_bandwidth_hz
    engine = build_engine(axis, mode="velocity", output_period_s=T)
    lead = axis.controller.drive.lead_m
    # a bias keeps the speed from reversing, so Coulomb friction stays a constant force
    v_bias, v_amp = 0.01, 1e-3

    def gain_db(f_hz: float) -> float:
        n_settle = int(0.03 / T)
        n = n_settle + round(10.0 / (f_hz * T))
        t = np.arange(n) * T
        ref = np.zeros((n, sig.REF_SIZE))
        ref[:, sig.REF_VEL_EXT_M_S] = v_bias + v_amp * np.sin(2 * np.pi * f_hz * t)
        res = engine.run(n, ref=ref)
        v = res["motor.omega"][n_settle:] * lead / (2 * math.pi)
        tt = res.t[n_settle:]
        basis = np.c_[
            np.sin(2 * np.pi * f_hz * tt), np.cos(2 * np.pi * f_hz * tt), np.ones(len(tt))
        ]
        fit = np.linalg.lstsq(basis, v, rcond=None)[0]
        return 20 * math.log10(math.hypot(fit[0], fit[1]) / v_amp)

    freqs = np.arange(300.0, 701.0, 50.0)
    gains = np.array([gain_db(f) for f in freqs])
    assert gains[0] > -3.0 > gains[-1]
    i = int(np.argmax(gains < -3.0))
    simulated_hz = freqs[i - 1] + (-3.0 - gains[i - 1]) / (gains[i] - gains[i - 1]) * 50.0
    assert simulated_hz == pytest.approx(design_hz, rel=0.15)


def _ramp_following_error(axis, v: float = 0.05, a: float = 2.0, t_end: float = 0.5):
    """Steady following error on an NC ramp (accelerate at a to v, then cruise)."""
    engine = build_engine(axis, output_period_s=T)
    n = round(t_end / T)
    div = round(axis.controller.nc_period_s / T)
    k = np.arange(n)
    t_nc = (k - k % div) * T  # the NC setpoint is held over its period
    t_a = v / a
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = np.where(
        t_nc < t_a, 0.5 * a * t_nc**2, 0.5 * a * t_a**2 + v * (t_nc - t_a)
    )
    ref[:, sig.REF_VEL_M_S] = np.where(t_nc < t_a, a * t_nc, v)
    ref[:, sig.REF_ACC_M_S2] = np.where(t_nc < t_a, a, 0.0)
    res = engine.run(n, ref=ref)
    assert np.all(res["out.fault"] == 0.0)
    steady = res.t > t_end - 0.1
    return float(np.mean(res["out.following_error_m"][steady]))


@pytest.mark.parametrize("feedback", ["linear_scale", "motor_encoder"])
def test_following_error_on_a_ramp_is_v_over_kv_and_velocity_ff_removes_it(feedback):
    pos = AXIS.controller.position
    v = 0.05
    plain = _with_controller(
        AXIS,
        position=dataclasses.replace(pos, feedback=feedback, velocity_ff=0.0, acceleration_ff=0.0),
    )
    error = _ramp_following_error(plain, v=v)
    assert error == pytest.approx(v / pos.Kv_1_s, rel=0.02)
    with_ff = _with_controller(
        AXIS,
        position=dataclasses.replace(pos, feedback=feedback, velocity_ff=1.0, acceleration_ff=0.0),
    )
    assert abs(_ramp_following_error(with_ff, v=v)) <= 0.05 * error


def test_following_error_trip_opens_the_power_stage_and_latches():
    pos = AXIS.controller.position
    # without feed-forward 0.1 m/s needs v/Kv = 3.3 mm of following error: above the 2 mm limit
    axis = _with_controller(
        AXIS, position=dataclasses.replace(pos, velocity_ff=0.0, acceleration_ff=0.0)
    )
    engine = build_engine(axis, output_period_s=T)
    v, a, t_end = 0.1, 2.0, 0.15
    n = round(t_end / T)
    div = round(axis.controller.nc_period_s / T)
    k = np.arange(n)
    t_nc = (k - k % div) * T
    t_a = v / a
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = np.where(
        t_nc < t_a, 0.5 * a * t_nc**2, 0.5 * a * t_a**2 + v * (t_nc - t_a)
    )
    ref[:, sig.REF_VEL_M_S] = np.where(t_nc < t_a, a * t_nc, v)
    res = engine.run(n, ref=ref)
    fault = res["out.fault"]
    j = int(np.argmax(fault != 0.0))
    assert j > 0 and np.all(fault[j:] == sig.FAULT_FOLLOWING_ERROR)
    error = res["out.following_error_m"]
    limit = pos.following_error_limit_m
    assert abs(error[j - 1]) <= limit < abs(error[j])
    assert np.all(res["out.enabled"][:j] == 1.0) and np.all(res["out.enabled"][j:] == 0.0)
    for phase in ("a", "b", "c"):
        assert np.all(res[f"out.duty_{phase}"][j + 1 :] == 0.5)
