"""PI anti-windup, biquad notch/low-pass designs and the FIR velocity estimator."""

import math

import numpy as np
import pytest

from feed_twin.control.blocks import (
    biquad_response,
    biquad_step,
    fir_velocity_step,
    lowpass1_alpha,
    lowpass2_coefficients,
    notch_coefficients,
    pi_step,
)

T = 1.0e-3


def _servo_integrator(setpoint: float, kp: float, ti: float, limit: float, steps: int):
    """PI around the plant y' = u (sampled, forward Euler); returns y and the integrator."""
    cs = np.zeros(1)
    y = 0.0
    ys, xs, us = [], [], []
    for _ in range(steps):
        u = pi_step(cs, 0, setpoint - y, kp, kp * T / ti, 0.0, -limit, limit)
        y += T * u
        ys.append(y)
        xs.append(cs[0])
        us.append(u)
    return np.array(ys), np.array(xs), np.array(us)


def test_pi_integrator_stops_in_saturation_and_overshoot_stays_at_the_linear_bound():
    kp, ti, limit, setpoint = 10.0, 0.5, 1.0, 5.0
    y, x_i, u = _servo_integrator(setpoint, kp, ti, limit, 8000)
    saturated = np.abs(u) >= limit
    assert saturated[:4000].all()  # 5 m at 1 m/s: saturated for about 4.9 s
    # conditional integration: not one sample of integration while pushed into the limit
    assert np.all(x_i[saturated & (np.arange(len(u)) < 4000)] == 0.0)
    # once the output leaves the limit the error is 1/Kp and the integrator is empty, so the rest
    # is the linear loop's response to a step of 1/Kp from rest
    y_lin, _, _ = _servo_integrator(1.0 / kp, kp, ti, math.inf, 4000)
    bound = y_lin.max() - 1.0 / kp
    overshoot = y.max() - setpoint
    assert 0.0 < overshoot <= 1.1 * bound
    assert y[-1] == pytest.approx(setpoint, abs=1e-3)
    # the same loop without anti-windup (limit only on the plant input) overshoots far more
    cs = np.zeros(1)
    y_w, yw_max = 0.0, 0.0
    for _ in range(8000):
        u_unlim = pi_step(cs, 0, setpoint - y_w, kp, kp * T / ti, 0.0, -math.inf, math.inf)
        y_w += T * min(max(u_unlim, -limit), limit)
        yw_max = max(yw_max, y_w)
    assert yw_max - setpoint > 10.0 * overshoot


def test_pi_integrator_resumes_when_the_error_reverses():
    cs = np.zeros(1)
    cs[0] = 0.5
    pi_step(cs, 0, 2.0, 1.0, 0.1, 0.0, -1.0, 1.0)  # saturated high, e > 0: hold
    assert cs[0] == 0.5
    pi_step(cs, 0, -0.2, 1.0, 0.1, 0.0, -1.0, 1.0)  # inside the limits: integrate
    assert cs[0] == pytest.approx(0.48)


@pytest.mark.parametrize("taps", [(1.0,), (0.5, 0.5), (0.25, 0.25, 0.25, 0.25), (1.5, -0.5)])
def test_fir_velocity_estimate_is_exact_on_a_ramp(taps):
    v_true, q0 = 0.0834, -0.12
    cp = np.array(taps)
    cs = np.zeros(len(taps) + 1)
    cs[len(taps)] = q0  # previous position
    for k in range(1, 12):
        v = fir_velocity_step(cp, 0, len(taps), cs, 0, len(taps), q0 + v_true * k * T, T)
        if k >= len(taps):
            assert v == pytest.approx(v_true, rel=1e-9)


def test_fir_two_tap_matches_the_emps_difference_of_averages():
    q = np.random.default_rng(1).normal(size=50)
    cp = np.array([0.5, 0.5])
    cs = np.zeros(3)
    cs[2] = q[0]
    for k in range(1, 50):
        v = fir_velocity_step(cp, 0, 2, cs, 0, 2, q[k], T)
        if k >= 2:
            qf, qf_prev = 0.5 * (q[k] + q[k - 1]), 0.5 * (q[k - 1] + q[k - 2])
            assert v == pytest.approx((qf - qf_prev) / T, rel=1e-12, abs=1e-9)


def _run_sine(coeffs, f_hz: float, period_s: float, cycles: int = 60) -> float:
    cp = np.array(coeffs)
    cs = np.zeros(2)
    n = int(cycles / (f_hz * period_s))
    t = np.arange(n) * period_s
    y = np.array([biquad_step(cp, 0, cs, 0, math.sin(2 * math.pi * f_hz * tk)) for tk in t])
    tail = y[n // 2 :]
    return float(np.sqrt(2.0 * np.mean(tail**2)))


def test_notch_gain_at_its_centre_equals_its_depth():
    period = 125e-6
    for f0, width, depth in [(400.0, 80.0, 0.0), (900.0, 200.0, 0.1), (1500.0, 300.0, 0.5)]:
        c = notch_coefficients(frequency_hz=f0, bandwidth_hz=width, depth=depth, period_s=period)
        assert abs(biquad_response(c, f0, period)) == pytest.approx(depth, abs=1e-9)
        assert abs(biquad_response(c, 1e-3, period)) == pytest.approx(1.0, abs=1e-9)
        assert abs(biquad_response(c, 0.5 / period - 1e-3, period)) == pytest.approx(1.0, abs=1e-6)
        # the time-domain kernel agrees with the formula
        assert _run_sine(c, f0, period) == pytest.approx(depth, abs=2e-3)
        assert _run_sine(c, 4.0 * f0, period) > 0.9


def test_second_order_lowpass_is_3db_down_at_its_corner():
    period = 250e-6
    c = lowpass2_coefficients(frequency_hz=300.0, period_s=period)
    assert abs(biquad_response(c, 300.0, period)) == pytest.approx(1.0 / math.sqrt(2.0), abs=1e-9)
    assert sum(c[:3]) / (1.0 + c[3] + c[4]) == pytest.approx(1.0, rel=1e-12)
    assert _run_sine(c, 300.0, period) == pytest.approx(1.0 / math.sqrt(2.0), abs=2e-3)


def test_first_order_lowpass_alpha_maps_the_pole_exactly():
    a = lowpass1_alpha(100.0, 1e-3)
    assert 1.0 - a == pytest.approx(math.exp(-2 * math.pi * 100.0 * 1e-3), rel=1e-12)


def test_filter_design_rejects_frequencies_beyond_nyquist():
    with pytest.raises(ValueError, match=r"frequency 5000.0 Hz must lie in \(0, 2000.0\) Hz"):
        notch_coefficients(frequency_hz=5000.0, bandwidth_hz=10.0, depth=0.0, period_s=250e-6)
