"""The compiled cascade tick: computation delay, FOC internals, modes, rates, interpolation,
drive behaviour (enable, faults) and the ros2_control-shaped classes that share its kernels."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from controller_support import current_loop, position_loop, velocity_loop

from feed_twin.control import cascade as cc
from feed_twin.control import config as ccfg
from feed_twin.control import layout as lay
from feed_twin.control.loops import (
    Cascade,
    CurrentLoop,
    PositionLoop,
    VelocityLoop,
    VelocitySetpoint,
)
from feed_twin.control.transforms import SQRT3, clarke, inverse_clarke, inverse_park, park
from feed_twin.core import signals as sig
from feed_twin.core.config import load_yaml

FIXTURES = Path(__file__).parent / "fixtures"
U_DC = 560.0


def _config(name: str, **changes) -> ccfg.ControllerConfig:
    path = FIXTURES / name
    config = ccfg.load_controller_config(load_yaml(path)["controller"], source=str(path))
    return dataclasses.replace(config, **changes)


AXIS = _config("controller_axis.yaml")
EMPS = _config("controller_emps.yaml")


class Rig:
    """Drives cascade_tick by hand with settable ref and meas vectors."""

    def __init__(self, config: ccfg.ControllerConfig) -> None:
        self.cascade = lay.build_cascade(config)
        self.cs = self.cascade.initial_state()
        self.ref = np.zeros(sig.REF_SIZE)
        self.meas = np.zeros(sig.MEAS_SIZE)
        self.meas[sig.MEAS_U_DC_V] = U_DC
        self.out = np.zeros(sig.OUT_SIZE)

    def tick(self, k: int) -> np.ndarray:
        cc.cascade_tick(self.cascade.params, self.cs, k, self.ref, self.meas, self.out)
        return self.out.copy()


def _voltage_dq(out: np.ndarray, theta_e: float) -> tuple[float, float]:
    """(u_d, u_q) that the duties in `out` make an averaged inverter apply."""
    phases = [(out[sig.OUT_DUTY_A + i] - 0.5) * U_DC for i in range(3)]
    return park(*clarke(*phases), theta_e)


def test_duties_computed_at_tick_k_apply_from_tick_k_plus_one():
    kp = current_loop(AXIS).Kp_q_V_A
    rig = Rig(dataclasses.replace(AXIS, mode="torque"))
    rig.ref[sig.REF_I_Q_EXT_A] = 2.0
    first = rig.tick(0)
    assert first[sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1] == pytest.approx([0.5, 0.5, 0.5])
    second = rig.tick(1)
    # the first sample's output: u_q = Kp*e with an empty integrator, at theta_e = 0
    assert _voltage_dq(second, 0.0) == pytest.approx((0.0, kp * 2.0), abs=1e-9)
    prompt = Rig(dataclasses.replace(AXIS, mode="torque", computation_delay=False))
    prompt.ref[sig.REF_I_Q_EXT_A] = 2.0
    assert _voltage_dq(prompt.tick(0), 0.0) == pytest.approx((0.0, kp * 2.0), abs=1e-9)


def test_park_angle_is_encoder_times_pole_pairs_and_decoupling_feeds_forward():
    config = dataclasses.replace(AXIS, mode="torque", computation_delay=False)
    cur = current_loop(config)
    rig = Rig(config)
    theta_m = 0.7
    theta_e = cur.pole_pairs * theta_m
    rig.meas[sig.MEAS_THETA_ENC_RAD] = theta_m
    i_d, i_q = 0.5, 3.0
    rig.meas[sig.MEAS_I_A : sig.MEAS_I_C + 1] = inverse_clarke(*inverse_park(i_d, i_q, theta_e))
    rig.ref[sig.REF_I_Q_EXT_A] = i_q
    v_load = 0.05  # m/s
    rig.cs[lay.S_INITIALISED] = lay.STARTED
    rig.cs[lay.S_VEL_EST] = v_load
    rig.cs[lay.S_ENC_POS_PREV] = theta_m * config.drive.lead_m / (2 * math.pi)
    rig.cs[lay.S_FIR_HIST : lay.S_FIR_HIST + 2] = v_load
    rig.cs[lay.S_ENC_POS_PREV] -= v_load * velocity_loop(config).period_s
    out = rig.tick(0)
    omega_e = cur.pole_pairs * v_load * 2 * math.pi / config.drive.lead_m
    u_d_expected = cur.Kp_d_V_A * (0.0 - i_d) - omega_e * cur.L_q_H * i_q
    u_q_expected = omega_e * (cur.L_d_H * i_d + cur.psi_pm_Vs)  # e_q = 0
    assert out[sig.OUT_VEL_EST_M_S] == pytest.approx(v_load, rel=1e-9)
    assert out[sig.OUT_U_D_REF_V] == pytest.approx(u_d_expected, rel=1e-9)
    assert out[sig.OUT_U_Q_REF_V] == pytest.approx(u_q_expected, rel=1e-9)
    assert _voltage_dq(out, theta_e) == pytest.approx((u_d_expected, u_q_expected), rel=1e-9)


def test_angle_advance_rotates_the_output_vector():
    base = dataclasses.replace(AXIS, mode="torque", computation_delay=False)
    advanced = dataclasses.replace(
        base, current=dataclasses.replace(current_loop(base), angle_advance_periods=1.5)
    )
    outs = []
    for config in (base, advanced):
        rig = Rig(config)
        rig.ref[sig.REF_I_Q_EXT_A] = 1.0
        rig.cs[lay.S_INITIALISED] = lay.STARTED
        rig.cs[lay.S_VEL_EST] = 0.2
        rig.cs[lay.S_FIR_HIST : lay.S_FIR_HIST + 2] = 0.2
        rig.cs[lay.S_ENC_POS_PREV] = -0.2 * velocity_loop(config).period_s
        outs.append(rig.tick(0))
    omega_e = 4 * 0.2 * 2 * math.pi / 0.01
    angle = 1.5 * omega_e * 62.5e-6
    plain = _voltage_dq(outs[0], 0.0)
    rotated = _voltage_dq(outs[1], angle)
    assert rotated == pytest.approx(plain, rel=1e-9)


def test_voltage_is_limited_to_the_inverter_circle_and_integrator_holds():
    rig = Rig(dataclasses.replace(AXIS, mode="torque", computation_delay=False))
    rig.ref[sig.REF_I_Q_EXT_A] = 30.0  # Kp * 30 A = 640 V > 0.95 * 560 / sqrt(3)
    for k in range(50):
        out = rig.tick(k)
        u = math.hypot(out[sig.OUT_U_D_REF_V], out[sig.OUT_U_Q_REF_V])
        assert u == pytest.approx(0.95 * U_DC / SQRT3, rel=1e-9)
        assert min(out[sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1]) >= 0.0
        assert max(out[sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1]) <= 1.0
    assert rig.cs[lay.S_I_Q_INT] == 0.0


def test_torque_mode_clamps_to_the_current_limit():
    rig = Rig(dataclasses.replace(AXIS, mode="torque"))
    rig.ref[sig.REF_I_Q_EXT_A] = 100.0
    assert rig.tick(0)[sig.OUT_I_Q_REF_A] == AXIS.drive.effort_limit


def test_loops_run_at_their_own_rates():
    base = lay.build_cascade(AXIS)
    divs = {n: base.params[i] for n, i in (("pos", lay.P_POS_DIV), ("vel", lay.P_VEL_DIV))}
    assert divs == {"pos": 4, "vel": 2}
    rig = Rig(AXIS)
    rig.ref[sig.REF_POS_M] = 0.0
    changes = []
    last = None
    for k in range(16):
        rig.meas[sig.MEAS_THETA_ENC_RAD] = 1e-3 * k * k  # accelerating: the estimate changes
        out = rig.tick(k)
        if last is not None and out[sig.OUT_VEL_EST_M_S] != last:
            changes.append(k)
        last = out[sig.OUT_VEL_EST_M_S]
    assert changes == list(range(2, 16, 2))


def _ramp_rig(interpolation: str) -> tuple[Rig, float, float]:
    config = dataclasses.replace(
        AXIS, position=dataclasses.replace(position_loop(AXIS), interpolation=interpolation)
    )
    return Rig(config), 0.2, config.nc_period_s


@pytest.mark.parametrize("interpolation", ["hold", "linear", "extrapolate", "cubic"])
def test_fine_interpolation_of_an_nc_ramp(interpolation):
    rig, v, t_nc = _ramp_rig(interpolation)
    base = AXIS.base_period_s
    nc_div = round(t_nc / base)
    pos_div = round(position_loop(AXIS).period_s / base)
    for k in range(0, 5 * nc_div):
        if k % nc_div == 0:
            rig.ref[sig.REF_POS_M] = v * k * base
            rig.ref[sig.REF_VEL_M_S] = v
        out = rig.tick(k)
        if k % pos_div or k < nc_div:
            continue
        t = k * base
        expected = {
            "hold": v * (k - k % nc_div) * base,
            "linear": v * (t - t_nc),
            "extrapolate": v * t,
            "cubic": v * (t - t_nc),
        }[interpolation]
        assert out[sig.OUT_POS_REF_M] == pytest.approx(expected, rel=1e-12, abs=1e-15)


def _cubic(t: float) -> tuple[float, float, float]:
    """x, v, a of x(t) = 0.1 + 0.2 t - 3 t^2 + 40 t^3 [m, s]."""
    return 0.1 + 0.2 * t - 3.0 * t**2 + 40.0 * t**3, 0.2 - 6.0 * t + 120.0 * t**2, -6.0 + 240.0 * t


def test_cubic_interpolation_reproduces_a_cubic_one_nc_period_late():
    """A Hermite segment through two samples' positions and velocities is the cubic itself."""
    t_nc, t0 = 1e-3, 0.02
    prev = _cubic(t0)
    cur = _cubic(t0 + t_nc)
    for s in (0.0, 0.25, 0.5, 0.875, 1.0):
        x, v, a = cc.interpolate(ccfg.INTERP_CUBIC, s, t_nc, prev, cur)
        assert (x, v, a) == pytest.approx(_cubic(t0 + s * t_nc), rel=1e-9, abs=1e-12)


def test_cubic_interpolation_equals_scipys_hermite_spline():
    """On arbitrary samples (no polynomial behind them): scipy's CubicHermiteSpline through
    the same positions and velocities, its value and first two derivatives."""
    from scipy.interpolate import CubicHermiteSpline

    rng = np.random.default_rng(3)
    t_nc = 1e-3
    x, v = rng.normal(0.0, 1e-4, 2), rng.normal(0.0, 0.1, 2)
    spline = CubicHermiteSpline([0.0, t_nc], x, v)
    for s in np.linspace(0.0, 1.0, 9):
        got = cc.interpolate(ccfg.INTERP_CUBIC, s, t_nc, (x[0], v[0], 0.0), (x[1], v[1], 0.0))
        want = tuple(float(spline(s * t_nc, nu)) for nu in range(3))
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("rate", ["position", "velocity"])
def test_feed_forward_at_the_velocity_rate_holds_only_the_position_loops_part(rate):
    """An NC ramp of the speed (constant acceleration): at the position rate the whole
    velocity command is held between position samples; at the velocity rate the speed
    feed-forward is interpolated at each velocity sample and only Kv e is held."""
    position = dataclasses.replace(position_loop(AXIS), feed_forward_rate=rate, acceleration_ff=0.0)
    rig = Rig(dataclasses.replace(AXIS, position=position))
    base, t_nc, acc = AXIS.base_period_s, AXIS.nc_period_s, 2.0
    nc_div = round(t_nc / base)
    pos_div = round(position.period_s / base)
    vel_div = round(velocity_loop(AXIS).period_s / base)
    assert pos_div == 2 * vel_div  # the axis' position loop runs at half the velocity rate
    x_meas = -1e-4
    rig.meas[sig.MEAS_X_SCALE_M] = x_meas
    for k in range(3 * nc_div):
        t = k * base
        if k % nc_div == 0:
            rig.ref[sig.REF_POS_M : sig.REF_ACC_M_S2 + 1] = (0.5 * acc * t * t, acc * t, acc)
        out = rig.tick(k)
        if k < nc_div or k % vel_div:
            continue
        t_pos = (k - k % pos_div) * base  # the latest position-loop sample
        e = _chord(acc, t_pos, t_nc) - x_meas
        t_ff = t if rate == "velocity" else t_pos
        v_ff = acc * (t_ff - t_nc)  # the speed ramps linearly: linear interpolation is exact
        want = position_loop(AXIS).Kv_1_s * e + v_ff
        assert out[sig.OUT_VEL_REF_M_S] == pytest.approx(want, rel=1e-12, abs=1e-15)


def _chord(acc: float, t: float, t_nc: float) -> float:
    """The linear interpolator's position at t on NC samples of 0.5 acc t^2: the chord between
    the two samples one NC period back."""
    latched = math.floor(t / t_nc + 1e-9) * t_nc
    s = (t - latched) / t_nc
    return 0.5 * acc * ((1.0 - s) * (latched - t_nc) ** 2 + s * latched**2)


def test_position_loop_law_with_feed_forward():
    rig = Rig(AXIS)
    x_ref, v_ref, a_ref, x_meas = 0.01, 0.1, 2.0, 0.0099
    rig.ref[sig.REF_POS_M : sig.REF_ACC_M_S2 + 1] = (x_ref, v_ref, a_ref)
    rig.meas[sig.MEAS_X_SCALE_M] = x_meas
    rig.meas[sig.MEAS_THETA_ENC_RAD] = 5.0  # ignored: closed loop on the scale
    out = rig.tick(0)
    assert out[sig.OUT_FOLLOWING_ERROR_M] == pytest.approx(x_ref - x_meas)
    assert out[sig.OUT_VEL_REF_M_S] == pytest.approx(50.0 * 1e-4 + v_ref)
    assert rig.cs[lay.S_EFFORT_FF] == pytest.approx(a_ref * 2 * math.pi / 0.01 * 5.8e-3 / 1.9)


def test_emps_velocity_mode_takes_the_external_setpoint():
    rig = Rig(dataclasses.replace(EMPS, mode="velocity"))
    rig.ref[sig.REF_POS_M] = 1.0  # ignored in velocity mode
    rig.ref[sig.REF_VEL_EXT_M_S] = 0.01
    assert rig.tick(0)[sig.OUT_EFFORT_CMD] == pytest.approx(243.45 * 0.01)


def test_following_error_trips_latches_and_clears():
    config = dataclasses.replace(
        EMPS, position=dataclasses.replace(position_loop(EMPS), following_error_limit_m=1e-3)
    )
    rig = Rig(config)
    rig.ref[sig.REF_POS_M] = 1e-4
    out = rig.tick(0)
    assert out[sig.OUT_FAULT] == sig.FAULT_NONE and out[sig.OUT_ENABLED] == 1.0
    assert out[sig.OUT_EFFORT_CMD] == pytest.approx(160.18 * 243.45 * 1e-4)
    rig.ref[sig.REF_POS_M] = 2e-3
    out = rig.tick(1)
    assert out[sig.OUT_FAULT] == sig.FAULT_FOLLOWING_ERROR
    assert lay.fault_reason(out[sig.OUT_FAULT]) == "following error limit exceeded"
    assert out[sig.OUT_ENABLED] == 0.0 and out[sig.OUT_EFFORT_CMD] == 0.0
    rig.ref[sig.REF_POS_M] = 0.0
    assert rig.tick(2)[sig.OUT_FAULT] == sig.FAULT_FOLLOWING_ERROR  # latched
    lay.clear_fault(rig.cs)
    out = rig.tick(3)
    assert out[sig.OUT_FAULT] == sig.FAULT_NONE and out[sig.OUT_ENABLED] == 1.0


def test_overcurrent_trips_and_the_power_stage_goes_to_zero_voltage():
    rig = Rig(AXIS)
    rig.tick(0)
    rig.meas[sig.MEAS_I_B] = -46.0
    out = rig.tick(1)
    assert out[sig.OUT_FAULT] == sig.FAULT_OVERCURRENT
    assert list(out[sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1]) == [0.5, 0.5, 0.5]
    assert rig.cs[lay.S_I_Q_INT] == 0.0 and rig.cs[lay.S_VEL_INT] == 0.0


def test_disable_clears_integrators_and_enable_resumes():
    rig = Rig(dataclasses.replace(AXIS, mode="velocity"))
    rig.ref[sig.REF_VEL_EXT_M_S] = 0.005  # 12.8 A: inside the current limit
    for k in range(10):
        rig.tick(k)
    assert rig.cs[lay.S_VEL_INT] > 0.0
    lay.disable(rig.cs)
    out = rig.tick(10)
    assert out[sig.OUT_FAULT] == sig.FAULT_DISABLED and out[sig.OUT_ENABLED] == 0.0
    assert rig.cs[lay.S_VEL_INT] == 0.0 and out[sig.OUT_I_Q_REF_A] == 0.0
    lay.enable(rig.cs)
    out = rig.tick(12)
    assert out[sig.OUT_FAULT] == sig.FAULT_NONE and out[sig.OUT_ENABLED] == 1.0
    assert out[sig.OUT_I_Q_REF_A] > 0.0
    rig_off = Rig(dataclasses.replace(AXIS, enabled_at_start=False))
    assert rig_off.tick(0)[sig.OUT_ENABLED] == 0.0


def test_cascade_class_equals_the_engine_tick():
    rig = Rig(EMPS)
    ctrl = Cascade(EMPS)
    rng = np.random.default_rng(3)
    for k in range(30):
        rig.ref[sig.REF_POS_M] = 1e-3 * k
        rig.meas[sig.MEAS_THETA_ENC_RAD] = rng.normal() * 1e-2
        expected = rig.tick(k)
        got = ctrl.update(k * 1e-3, rig.ref, rig.meas)
        assert np.array_equal(got, expected)
    ctrl.reset()
    assert ctrl.state["initialised"] == 0.0


def test_loop_classes_call_the_same_laws():
    meas = np.zeros(sig.MEAS_SIZE)
    meas[sig.MEAS_U_DC_V] = U_DC
    meas[sig.MEAS_X_SCALE_M] = 0.004
    ref = np.zeros(sig.REF_SIZE)
    ref[sig.REF_POS_M : sig.REF_VEL_M_S + 1] = (0.005, 0.02)
    cmd = PositionLoop(AXIS).update(0.0, ref, meas)
    assert cmd.vel_ref_m_s == pytest.approx(50.0 * 0.001 + 0.02)
    assert cmd.following_error_m == pytest.approx(0.001)
    vel = VelocityLoop(EMPS)
    assert vel.update(0.0, VelocitySetpoint(vel_m_s=0.02), meas) == pytest.approx(243.45 * 0.02)
    cur = CurrentLoop(AXIS)
    assert cur.update(0.0, 2.0, meas) == (0.5, 0.5, 0.5)  # computation delay
    rig = Rig(dataclasses.replace(AXIS, mode="torque"))
    rig.ref[sig.REF_I_Q_EXT_A] = 2.0
    rig.tick(0)
    assert cur.update(62.5e-6, 2.0, meas) == pytest.approx(
        tuple(rig.tick(1)[sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1]), abs=1e-12
    )


def test_loop_classes_reject_off_grid_and_repeated_times():
    loop = PositionLoop(AXIS)
    ref, meas = np.zeros(sig.REF_SIZE), np.zeros(sig.MEAS_SIZE)
    with pytest.raises(ValueError) as err:
        loop.update(1e-4, ref, meas)
    assert str(err.value) == "t = 0.0001 s: not a sample instant of this loop (period 0.00025 s)"
    loop.update(2.5e-4, ref, meas)
    with pytest.raises(ValueError) as err:
        loop.update(2.5e-4, ref, meas)
    assert str(err.value) == "t = 0.00025 s: not after the previous update at 0.00025 s"
    with pytest.raises(ValueError, match=r"measurement: expected a vector of 6 floats"):
        loop.update(5e-4, ref, np.zeros(3))
    with pytest.raises(ValueError, match="PositionLoop: the configuration has no position"):
        PositionLoop(dataclasses.replace(EMPS, mode="velocity", position=None))
    with pytest.raises(ValueError, match="CurrentLoop: the configuration has no current"):
        CurrentLoop(EMPS)


@pytest.mark.parametrize("taps", [(1.0,), (0.5, 0.5), (0.25, 0.25, 0.25, 0.25), (1.5, -0.5)])
def test_fir_velocity_estimate_is_exact_on_a_ramp(taps):
    config = dataclasses.replace(
        EMPS,
        velocity=dataclasses.replace(
            velocity_loop(EMPS), estimator=ccfg.VelocityEstimatorConfig(fir_taps=taps)
        ),
    )
    loop = VelocityLoop(config)
    meas = np.zeros(sig.MEAS_SIZE)
    v_true, x0 = 0.0834, -0.12
    rad_per_m = 2 * math.pi / config.drive.lead_m
    for k in range(12):
        meas[sig.MEAS_THETA_ENC_RAD] = (x0 + v_true * k * 1e-3) * rad_per_m
        loop.update(k * 1e-3, VelocitySetpoint(vel_m_s=0.0), meas)
        if k >= len(taps):
            assert loop.velocity_estimate_m_s == pytest.approx(v_true, rel=1e-9)


def test_emps_fir_is_the_difference_of_two_sample_averages():
    q = np.random.default_rng(1).normal(size=50) * 1e-3
    loop = VelocityLoop(EMPS)
    meas = np.zeros(sig.MEAS_SIZE)
    for k in range(50):
        meas[sig.MEAS_THETA_ENC_RAD] = q[k] * 2 * math.pi / EMPS.drive.lead_m
        loop.update(k * 1e-3, VelocitySetpoint(vel_m_s=0.0), meas)
        if k >= 2:
            qf, qf_prev = 0.5 * (q[k] + q[k - 1]), 0.5 * (q[k - 1] + q[k - 2])
            assert loop.velocity_estimate_m_s == pytest.approx((qf - qf_prev) / 1e-3, rel=1e-9)


def test_estimator_lowpass_is_first_order_with_its_corner_frequency():
    f_c = 50.0
    config = dataclasses.replace(
        EMPS,
        velocity=dataclasses.replace(
            velocity_loop(EMPS),
            estimator=ccfg.VelocityEstimatorConfig(fir_taps=(1.0,), lowpass_hz=f_c),
        ),
    )
    loop = VelocityLoop(config)
    meas = np.zeros(sig.MEAS_SIZE)
    v_true = 0.05
    pole = math.exp(-2 * math.pi * f_c * 1e-3)  # the continuous pole mapped exactly
    for k in range(60):
        meas[sig.MEAS_THETA_ENC_RAD] = v_true * k * 1e-3 * 2 * math.pi / config.drive.lead_m
        loop.update(k * 1e-3, VelocitySetpoint(vel_m_s=0.0), meas)
        # the ramp's differences reach the filter from k = 1: a sampled first-order step response
        expected = v_true * (1 - pole**k)
        assert loop.velocity_estimate_m_s == pytest.approx(expected, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("depth", [0.0, 0.2])
def test_notch_on_the_current_setpoint_attenuates_at_its_centre(depth):
    f0, T_v = 100.0, 1e-3
    plain = dataclasses.replace(
        EMPS,
        velocity=dataclasses.replace(
            velocity_loop(EMPS), estimator=ccfg.VelocityEstimatorConfig(fir_taps=(1.0,))
        ),
    )
    notch = ccfg.NotchConfig(frequency_hz=f0, bandwidth_hz=40.0, depth=depth)
    notched = dataclasses.replace(
        plain, velocity=dataclasses.replace(velocity_loop(plain), notch=notch)
    )
    amplitudes = []
    for config in (plain, notched):
        loop = VelocityLoop(config)
        meas = np.zeros(sig.MEAS_SIZE)
        outputs = []
        for k in range(600):
            x = 1e-5 * math.sin(2 * math.pi * f0 * k * T_v)
            meas[sig.MEAS_THETA_ENC_RAD] = x * 2 * math.pi / config.drive.lead_m
            outputs.append(loop.update(k * T_v, VelocitySetpoint(vel_m_s=0.0), meas))
        amplitudes.append(np.max(np.abs(outputs[300:])))
    assert amplitudes[1] / amplitudes[0] == pytest.approx(depth, abs=0.01)
