"""The inlined sincos against libm: within two units in the last place over the angles a run
reaches, exact at the quadrant points, NaN propagated (the divergence check relies on it)."""

import math

import numpy as np
from numba import njit

from feed_twin.core.trig import NEAR, sincos, sincos_anchored, sincos_near


@njit  # no cache: numba would not notice a change of the callee
def _many(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.empty(theta.size)
    s = np.empty(theta.size)
    for i in range(theta.size):
        c[i], s[i] = sincos(theta[i])
    return c, s


def test_sincos_is_within_two_ulp_of_libm():
    rng = np.random.default_rng(5)
    # electrical angles: a motor at 6000 rpm with 4 pole pairs turns 2500 rad per second of
    # simulation; 1e6 rad is several minutes
    for scale in (1.0, 100.0, 1e4, 1e6):
        theta = rng.uniform(-scale, scale, 200_000)
        c, s = _many(theta)
        for mine, ref in ((c, np.cos(theta)), (s, np.sin(theta))):
            # one ulp of the value, at least one ulp of a result near 1 in size for the
            # cancellation near a zero of the function
            ulp = np.spacing(np.maximum(np.abs(ref), 2.0**-53))
            assert np.max(np.abs(mine - ref) / ulp) <= 2.0


def test_quadrant_points_and_special_values():
    points = np.array([0.0, 0.5 * math.pi, math.pi, -0.5 * math.pi, 1e-300])
    c, s = _many(points)
    # the double nearest pi/2 is not pi/2: cos of it is 6.1e-17, as libm has it
    np.testing.assert_allclose(c, np.cos(points), rtol=0.0, atol=2e-17)
    np.testing.assert_allclose(s, np.sin(points), rtol=0.0, atol=2e-17)
    assert c[0] == 1.0 and s[0] == 0.0 and s[4] == 1e-300  # sin(x) = x for tiny x, exactly
    c, s = _many(np.array([math.nan, math.inf]))
    assert np.isnan(c).all() and np.isnan(s).all()


@njit
def _many_near(theta: np.ndarray, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.empty(theta.size)
    s = np.empty(theta.size)
    for i in range(theta.size):
        c0, s0 = sincos(theta0[i])
        c[i], s[i] = sincos_near(theta[i], theta0[i], c0, s0)
    return c, s


def test_sincos_near_rotates_a_known_pair_to_within_four_ulp_of_libm():
    """The RK4 stages rotate the tick's Park angle by what the rotor turned since: up to NEAR.

    A rotation is accurate relative to the length of the (cos, sin) vector, 1: near a zero of
    either function the error is a few units of 1/2's last place, not of the tiny value's."""
    rng = np.random.default_rng(7)
    for scale in (1.0, 1e3, 1e5):
        theta0 = rng.uniform(-scale, scale, 200_000)
        theta = theta0 + rng.uniform(-NEAR, NEAR, theta0.size)
        c, s = _many_near(theta, theta0)
        for mine, ref in ((c, np.cos(theta)), (s, np.sin(theta))):
            ulp = np.spacing(np.maximum(np.abs(ref), 0.5))
            assert np.max(np.abs(mine - ref) / ulp) <= 4.0


def test_sincos_near_is_exact_at_its_own_angle_and_falls_back_far_from_it():
    theta0 = np.array([0.3, -2.0, 1234.5])
    c0, s0 = _many(theta0)
    c, s = _many_near(theta0, theta0)
    assert np.array_equal(c, c0) and np.array_equal(s, s0)  # d = 0: the pair itself, bit for bit
    far = theta0 + 1.5 * NEAR
    c, s = _many_near(far, theta0)
    c_ref, s_ref = _many(far)
    assert np.array_equal(c, c_ref) and np.array_equal(s, s_ref)  # beyond NEAR: sincos itself
    c, s = _many_near(np.array([math.nan, math.inf]), np.array([0.0, 0.0]))
    assert np.isnan(c).all() and np.isnan(s).all()  # the divergence check relies on it
    c, s = _many_near(np.array([1.0]), np.array([math.nan]))
    assert (c[0], s[0]) == tuple(v[0] for v in _many(np.array([1.0])))  # no pair: sincos


@njit
def _anchored_run(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    c = np.empty(theta.size)
    s = np.empty(theta.size)
    anchor = (0.0, 1.0, 0.0)
    renewed = 0
    for i in range(theta.size):
        c[i], s[i], a_theta, a_c, a_s = sincos_anchored(theta[i], anchor[0], anchor[1], anchor[2])
        renewed += a_theta != anchor[0]
        anchor = (a_theta, a_c, a_s)
    return c, s, renewed


def test_the_anchored_pair_does_not_drift_over_a_long_run():
    """The drive's encoder angle tick by tick for 10 s at 16 kHz, speeding up and reversing:
    each pair is one rotation from an exact evaluation, so the error stays at a few ulp."""
    t = np.arange(160_000) * 62.5e-6
    omega_e = 2500.0 * np.sin(2.0 * np.pi * 0.3 * t)  # up to 6000 rpm with 4 pole pairs
    theta = np.cumsum(omega_e) * 62.5e-6
    c, s, renewed = _anchored_run(theta)
    for mine, ref in ((c, np.cos(theta)), (s, np.sin(theta))):
        assert np.max(np.abs(mine - ref) / np.spacing(np.maximum(np.abs(ref), 0.5))) <= 4.0
    # a new anchor only once the angle is more than NEAR from the last one, and so at most one
    # tick's step beyond it
    travel = np.sum(np.abs(np.diff(theta)))
    step = np.max(np.abs(np.diff(theta)))
    assert travel / (NEAR + step) <= renewed <= travel / NEAR + 10
