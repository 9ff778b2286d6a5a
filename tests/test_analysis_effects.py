"""Effect signatures and their ranking on residuals built from known effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.analysis.effects import BY_NAME, LIBRARY, Effect, motion_from_position
from feed_twin.analysis.ranking import evidence, rank

H = 1e-3
REQUIRED = {
    "coulomb_friction",
    "stribeck_friction",
    "viscous_friction",
    "asymmetric_friction",
    "backlash",
    "constant_force",
    "mass_error",
    "torque_constant_error",
    "position_dependent_stiffness",
    "cogging_torque",
    "lead_error",
    "current_offset",
    "dead_time",
    "thermal_drift",
    "measurement_delay",
    "stiction",
    "channel_delay",
    "position_delay",  # issue 27: the trace between machine and record
    "trace_window",
    "command_delay",  # the drive's setpoint latency against the twin's loops
    "friction_drift",  # issue 27: a friction that changes over the record
}


def _motion(seed: int = 0):
    t = H * np.arange(12000, dtype=np.float64)
    # trapezoid-like back-and-forth moves of 0.1 m with dwell, plus a slow creep sweep
    x = 0.05 * (1 - np.cos(2 * math.pi * 0.25 * t)) ** 1.5 / 2**0.5 + 0.005 * np.sin(
        2 * math.pi * 0.9 * t
    )
    effort = 95.0 * np.gradient(np.gradient(x, H), H) + 200.0 * np.gradient(x, H)
    rng = np.random.default_rng(seed)
    x_q = np.round((x + rng.normal(0, 2e-8, t.size)) / 5e-8) * 5e-8  # encoder counts
    return motion_from_position(
        t, x_q, effort_sim=effort, lead_m=0.0025, pole_pairs=4, travel_m=0.3
    )


def test_library_holds_every_identifier_of_the_issue():
    assert {e.name for e in LIBRARY} == REQUIRED
    assert all(e.words and e.component for e in LIBRARY)


def test_effect_needs_exactly_one_signature_kind():
    with pytest.raises(ValueError, match="effect x: give exactly one of signature and choices"):
        Effect(
            name="x",
            domain="effort",
            parameters="c",
            words="w",
            edit=BY_NAME["coulomb_friction"].edit,
            truth=BY_NAME["coulomb_friction"].truth,
        )


@pytest.mark.parametrize(
    ("truth", "make"),
    [
        ("coulomb_friction", lambda m: 20.0 * np.sign(m.v_m_s)),
        ("viscous_friction", lambda m: 150.0 * m.v_m_s),
        ("constant_force", lambda m: np.full_like(m.t_s, -3.0)),
        ("mass_error", lambda m: 9.0 * m.a_m_s2),
        ("asymmetric_friction", lambda m: -40.0 * np.abs(m.v_m_s) + 1.0 * (m.v_m_s > 0)),
        (
            "stribeck_friction",
            lambda m: 15.0 * np.sign(m.v_m_s) * np.exp(-((m.v_m_s / 0.004) ** 2)),
        ),
        ("cogging_torque", lambda m: 4.0 * np.sin(6 * 2 * math.pi * m.x_m / 0.0025 + 0.3)),
        # a late measurement makes the effort follow the twin's effort shifted by the delay
        ("measurement_delay", lambda m: -0.002 * np.gradient(m.effort_sim, m.t_s)),
    ],
)
def test_hidden_effort_effect_is_ranked_first(truth, make):
    m = _motion()
    rng = np.random.default_rng(3)
    residual = make(m) + rng.normal(0.0, 0.5, m.t_s.size)
    ranked = rank(m, effort_residual=residual, position_residual=None)
    assert ranked[0].name == truth, [(c.name, c.explained_fraction) for c in ranked[:4]]
    assert ranked[0].significant
    assert "significant" in evidence(ranked[0], "N")


def test_coulomb_weight_estimates_the_friction_force():
    m = _motion()
    residual = 20.0 * np.sign(m.v_m_s) + np.random.default_rng(4).normal(0, 0.5, m.t_s.size)
    top = rank(m, effort_residual=residual, position_residual=None)[0]
    # tanh regularisation at 0.2 % of the peak speed: the weight is within 2 % of the step
    assert top.coefficients["sign_v"] == pytest.approx(20.0, rel=0.02)


def test_noise_alone_names_nothing():
    m = _motion()
    rng = np.random.default_rng(5)
    # coloured noise: white noise through a 20 ms moving average, like loop-filtered noise
    e = np.convolve(rng.normal(0, 1.0, m.t_s.size + 19), np.ones(20) / 20, "valid")
    p = np.convolve(rng.normal(0, 1e-7, m.t_s.size + 19), np.ones(20) / 20, "valid")
    ranked = rank(m, effort_residual=e, position_residual=p)
    assert not any(c.significant for c in ranked), [(c.name, c.p_value) for c in ranked[:3]]


@pytest.mark.parametrize(
    ("truth", "make"),
    [
        ("lead_error", lambda m: 3e-6 * np.sin(2 * math.pi * m.x_m / 0.0025)),
        ("thermal_drift", lambda m: 2e-5 * (m.x_m - m.x_m.min()) * m.t_s),
    ],
)
def test_hidden_position_effect_is_ranked_first(truth, make):
    m = _motion()
    rng = np.random.default_rng(6)
    residual = make(m) + rng.normal(0.0, 5e-8, m.t_s.size)
    ranked = rank(m, effort_residual=None, position_residual=residual)
    assert ranked[0].name == truth
    assert ranked[0].significant


def test_effort_driven_position_residual_is_not_blamed_on_position_effects():
    m = _motion()
    force = 20.0 * np.sign(m.v_m_s)
    # a stiff loop turns a missing force into a following-error change of force / K
    ranked = rank(m, effort_residual=force, position_residual=force / 1.4e6)
    assert ranked[0].name == "coulomb_friction"
    assert BY_NAME["backlash"].name not in [c.name for c in ranked if c.significant]


def _jerk_limited_motion():
    """The synthetic program's X motion as the jerk-limited planner plans it, with a twin
    effort of mass and a regularised Coulomb force."""
    from feed_twin.analysis.synthetic import command

    t, x = command()
    v = np.gradient(x, t)
    effort = 95.0 * np.gradient(v, t) + 20.0 * np.tanh(v / 1e-3)
    return motion_from_position(t, x, effort_sim=effort, lead_m=0.0025, pole_pairs=4, travel_m=0.1)


def test_a_drive_lag_is_not_taken_for_a_stribeck_hump():
    """A current loop that lags the command by T makes the recorded command lead the twin's by
    T dF/dt: on a jerk-limited start or stop, m T j while the speed is still low, a hump of the
    direction of motion that a Stribeck law of a few mm/s fits. Taken beyond the effort's rate
    it is no finding; a real hump of about the same size still is."""
    m = _jerk_limited_motion()
    rng = np.random.default_rng(7)
    assert m.effort_sim is not None
    lag = 2e-4 * np.gradient(m.effort_sim, m.t_s)  # 0.76 N on each 40 m/s^3 jerk phase
    noise = rng.normal(0.0, 0.1, m.t_s.size)
    ranked = rank(m, effort_residual=lag + noise, position_residual=None)
    found = [c.name for c in ranked if c.significant]
    assert "stribeck_friction" not in found, [(c.name, c.explained_fraction) for c in ranked]
    assert set(found) <= {"channel_delay", "measurement_delay"}, found
    hump = 1.5 * np.sign(m.v_m_s) * np.exp(-((m.v_m_s / 0.005) ** 2))
    ranked = rank(m, effort_residual=lag + hump + noise, position_residual=None)
    top = next(c for c in ranked if c.name == "stribeck_friction")
    assert top.significant, (top.explained_fraction, top.p_value)
