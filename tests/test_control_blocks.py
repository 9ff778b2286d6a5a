"""PI anti-windup and the biquad notch/low-pass designs (the FIR estimator is tested through the
velocity loop in test_control_cascade.py)."""

import math

import numpy as np
import pytest

from feed_twin.control.blocks import (
    biquad_response,
    biquad_update,
    lowpass1_alpha,
    lowpass2_coefficients,
    notch_coefficients,
    pi_update,
)

T = 1.0e-3


def _servo_integrator(setpoint: float, kp: float, ti: float, limit: float, steps: int):
    """PI around the plant y' = u (sampled, forward Euler); returns y and the integrator."""
    x_i = 0.0
    y = 0.0
    ys, xs, us = [], [], []
    for _ in range(steps):
        u, x_i = pi_update(x_i, setpoint - y, kp, kp * T / ti, 0.0, -limit, limit)
        y += T * u
        ys.append(y)
        xs.append(x_i)
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
    x_w, y_w, yw_max = 0.0, 0.0, 0.0
    for _ in range(8000):
        u_unlim, x_w = pi_update(x_w, setpoint - y_w, kp, kp * T / ti, 0.0, -math.inf, math.inf)
        y_w += T * min(max(u_unlim, -limit), limit)
        yw_max = max(yw_max, y_w)
    assert yw_max - setpoint > 10.0 * overshoot


def test_pi_integrator_resumes_when_the_error_reverses():
    u, x_i = pi_update(0.5, 2.0, 1.0, 0.1, 0.0, -1.0, 1.0)  # saturated high, e > 0: hold
    assert (u, x_i) == (1.0, 0.5)
    u, x_i = pi_update(x_i, -0.2, 1.0, 0.1, 0.0, -1.0, 1.0)  # inside the limits: integrate
    assert u == pytest.approx(0.3) and x_i == pytest.approx(0.48)


def _run_sine(
    coeffs: tuple[float, float, float, float, float], f_hz: float, period_s: float, cycles: int = 60
) -> float:
    s1 = s2 = 0.0
    n = int(cycles / (f_hz * period_s))
    y = np.empty(n)
    for k in range(n):
        y[k], s1, s2 = biquad_update(*coeffs, s1, s2, math.sin(2 * math.pi * f_hz * k * period_s))
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
