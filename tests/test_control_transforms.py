"""Clarke/Park round trips, the amplitude-invariant power factor, SVPWM and the modulator."""

import math

import numpy as np
import pytest

from feed_twin.control.transforms import (
    POWER_FACTOR_AMPLITUDE_INVARIANT,
    SQRT3,
    clarke,
    inverse_clarke,
    inverse_park,
    limit_voltage_circle,
    modulate,
    park,
    svpwm_duties,
)

RNG = np.random.default_rng(7)


def _phases(amplitude: float, angle: float, zero_seq: float = 0.0) -> tuple[float, float, float]:
    a, b, c = (amplitude * math.cos(angle - i * 2.0 * math.pi / 3.0) + zero_seq for i in range(3))
    return a, b, c


def test_clarke_of_balanced_set_has_the_phase_amplitude_and_angle():
    for amplitude, angle in RNG.uniform([0.1, -10.0], [50.0, 10.0], size=(20, 2)):
        x_alpha, x_beta = clarke(*_phases(amplitude, angle, zero_seq=3.7))
        assert math.hypot(x_alpha, x_beta) == pytest.approx(amplitude, rel=1e-12)
        assert math.atan2(x_beta, x_alpha) == pytest.approx(
            math.atan2(math.sin(angle), math.cos(angle)), abs=1e-12
        )


def test_clarke_inverse_clarke_round_trip():
    for x_alpha, x_beta in RNG.normal(size=(20, 2)) * 10.0:
        phases = inverse_clarke(x_alpha, x_beta)
        assert sum(phases) == pytest.approx(0.0, abs=1e-12)
        assert clarke(*phases) == pytest.approx((x_alpha, x_beta), abs=1e-12)


def test_park_round_trip_and_rotating_vector_is_constant_in_dq():
    for x_d, x_q, theta in RNG.normal(size=(20, 3)) * 5.0:
        assert park(*inverse_park(x_d, x_q, theta), theta) == pytest.approx((x_d, x_q), abs=1e-12)
    # a vector rotating with theta_e appears at rest in the d/q frame
    for theta in np.linspace(0.0, 20.0, 11):
        i_alpha, i_beta = clarke(*_phases(4.0, theta + 0.3))
        i_d, i_q = park(i_alpha, i_beta, theta)
        assert (i_d, i_q) == pytest.approx((4.0 * math.cos(0.3), 4.0 * math.sin(0.3)), abs=1e-12)


def test_power_in_the_dq_frame_is_three_halves_of_the_vector_product():
    for _ in range(20):
        u_amp, i_amp, th_u, th_i = RNG.uniform([1, 1, -3, -3], [400, 30, 3, 3])
        u = _phases(u_amp, th_u)
        i = _phases(i_amp, th_i)
        p_abc = sum(a * b for a, b in zip(u, i, strict=True))
        theta = RNG.uniform(-3, 3)
        u_d, u_q = park(*clarke(*u), theta)
        i_d, i_q = park(*clarke(*i), theta)
        p_dq = POWER_FACTOR_AMPLITUDE_INVARIANT * (u_d * i_d + u_q * i_q)
        assert p_dq == pytest.approx(p_abc, rel=1e-12)
        assert p_abc == pytest.approx(1.5 * u_amp * i_amp * math.cos(th_u - th_i), rel=1e-9)


def test_svpwm_produces_the_requested_line_voltages_inside_the_linear_range():
    u_dc = 560.0
    for radius in np.linspace(0.0, 1.0, 11) * u_dc / SQRT3:
        for angle in np.linspace(-math.pi, math.pi, 37):
            u_alpha, u_beta = radius * math.cos(angle), radius * math.sin(angle)
            d = svpwm_duties(u_alpha, u_beta, u_dc)
            assert min(d) >= 0.0 and max(d) <= 1.0
            u_a, u_b, u_c = inverse_clarke(u_alpha, u_beta)
            assert (d[0] - d[1]) * u_dc == pytest.approx(u_a - u_b, abs=1e-9 * u_dc)
            assert (d[1] - d[2]) * u_dc == pytest.approx(u_b - u_c, abs=1e-9 * u_dc)
            assert (d[2] - d[0]) * u_dc == pytest.approx(u_c - u_a, abs=1e-9 * u_dc)


def test_minmax_injection_reaches_udc_over_sqrt3_and_sine_pwm_would_not():
    u_dc = 600.0
    radius = u_dc / SQRT3
    spans = []
    for angle in np.linspace(0.0, 2.0 * math.pi, 721):
        d = svpwm_duties(radius * math.cos(angle), radius * math.sin(angle), u_dc)
        spans.append(max(d) - min(d))
        # at the edge of the hexagon's inscribed circle the duties just touch 0 and 1 ...
        assert min(d) >= -1e-12 and max(d) <= 1.0 + 1e-12
    # ... exactly where the line-to-line voltage peaks at u_dc
    assert max(spans) == pytest.approx(1.0, abs=1e-9)
    # without injection (sine-triangle PWM) the phase duty 1/2 + u_a/u_dc would exceed 1
    assert 0.5 + radius / u_dc > 1.0


def test_svpwm_clips_beyond_the_linear_range():
    d = svpwm_duties(1000.0, 0.0, 300.0)
    assert min(d) == 0.0 and max(d) == 1.0


def test_voltage_circle_limit_keeps_d_priority():
    assert limit_voltage_circle(3.0, 4.0, 10.0) == (3.0, 4.0)
    u_d, u_q = limit_voltage_circle(6.0, 20.0, 10.0)
    assert (u_d, u_q) == pytest.approx((6.0, 8.0))
    assert limit_voltage_circle(-30.0, 5.0, 10.0) == (-10.0, 0.0)


def test_modulator_gives_the_rotated_line_voltages_plus_the_dead_time_compensation():
    # line-to-line voltages (d_x - d_y) * u_dc = the inverse Park of (u_d, u_q) at theta, each
    # phase raised by u_comp * clip(i_x / band, -1, 1): with i = (2, -0.1, -1.9) A and a 0.5 A
    # band that is (+1, -0.2, -1) * u_comp
    u_dc, u_comp, band = 560.0, 10.0, 0.5
    i = (2.0, -0.1, -1.9)
    for theta in np.linspace(-3.0, 3.0, 13):
        u_d, u_q = 40.0, -150.0
        duties = modulate(u_d, u_q, math.cos(theta), math.sin(theta), *i, u_comp, band, u_dc)
        u = inverse_clarke(*inverse_park(u_d, u_q, theta))
        comp = (u_comp, -0.2 * u_comp, -u_comp)
        for x, y in ((0, 1), (1, 2), (2, 0)):
            expected = (u[x] + comp[x]) - (u[y] + comp[y])
            assert (duties[x] - duties[y]) * u_dc == pytest.approx(expected, abs=1e-9 * u_dc)
        plain = modulate(u_d, u_q, math.cos(theta), math.sin(theta), *i, 0.0, band, u_dc)
        assert (plain[0] - plain[1]) * u_dc == pytest.approx(u[0] - u[1], abs=1e-9 * u_dc)


def test_modulator_without_bus_voltage_gives_half_duties():
    assert modulate(10.0, 20.0, 1.0, 0.0, 1.0, 0.0, -1.0, 5.0, 0.5, 0.0) == (0.5, 0.5, 0.5)
