"""The plant's written-out elementary functions against their definitions: the C2 smooth sign
(feed_twin.core.smooth) and exp(-x) (feed_twin.plant.expneg, against libm)."""

import math

import numpy as np
from numba import njit

from feed_twin.core.smooth import WIDTH, smooth_sign, smooth_sign_array
from feed_twin.plant.expneg import X_MAX, exp_neg


@njit  # no cache: numba would not notice a change of the callee
def _exp_many(x: np.ndarray) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = exp_neg(x[i])
    return out


@njit
def _sign_many(x: np.ndarray, scale: float = 1.0) -> np.ndarray:
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = smooth_sign(x[i], scale)
    return out


def test_exp_neg_is_within_two_ulp_of_libm():
    rng = np.random.default_rng(3)
    # the Stribeck range (v/v_s)^2 < 50 densely, then the whole domain
    x = np.concatenate([np.linspace(0.0, 50.0, 400_001), rng.uniform(0.0, X_MAX, 200_000)])
    mine, ref = _exp_many(x), np.exp(-x)
    assert np.max(np.abs(mine - ref) / np.spacing(ref)) <= 2.0


def test_exp_neg_special_values():
    x = np.array([0.0, X_MAX + 1.0, 1e300, np.inf, np.nan])
    out = _exp_many(x)
    assert out[0] == 1.0
    assert np.all(out[1:4] == 0.0)  # below the normal range: 0, as the Stribeck term needs
    assert np.isnan(out[4])  # the divergence check relies on NaN passing through


def test_smooth_sign_is_an_odd_c2_sign_with_unit_slope_at_zero():
    x = np.linspace(-3.0, 3.0, 600_001)
    s = _sign_many(x)
    np.testing.assert_array_equal(_sign_many(-x), -s)  # odd
    np.testing.assert_array_equal(s[np.abs(x) >= WIDTH], np.sign(x[np.abs(x) >= WIDTH]))
    assert np.all(np.abs(s) <= 1.0) and np.all(np.diff(s) >= 0.0)  # monotone, bounded
    dx = x[1] - x[0]
    slope = np.gradient(s, dx)
    assert slope[len(x) // 2] == np.float64(slope.max())
    assert math.isclose(slope.max(), 1.0, rel_tol=1e-6)
    # first and second derivatives continuous at the band edges (C2): the finite differences
    # have no jump there beyond their own O(dx) error
    curvature = np.gradient(slope, dx)
    edge = np.argmin(np.abs(x - WIDTH))
    assert abs(slope[edge - 2]) < 1e-6 and abs(slope[edge + 2]) == 0.0
    assert abs(curvature[edge - 3]) < 1e-3 and abs(curvature[edge + 3]) == 0.0


def test_smooth_sign_against_its_polynomial_and_the_array_version():
    x = np.random.default_rng(4).uniform(-2.5, 2.5, 100_000)
    u = np.clip(x * 8.0 / 15.0, -1.0, 1.0)
    np.testing.assert_allclose(_sign_many(x), (15 * u - 10 * u**3 + 3 * u**5) / 8, atol=4e-16)
    np.testing.assert_array_equal(smooth_sign_array(x, 1.0), _sign_many(x))
    assert math.isnan(smooth_sign(math.nan, 1.0)) and smooth_sign(math.inf, 1.0) == 1.0


def test_the_scale_stretches_the_band():
    # sgn(x / s): slope 1/s at 0, exactly +/-1 from W s on, whatever the scale (v_reg = 1e-4 m/s,
    # i_reg = 0.5 A, P_REG = 1e-3 W)
    x = np.random.default_rng(6).uniform(-3.0, 3.0, 10_000)
    for scale in (1e-4, 0.5, 1e-3, 7.0):
        np.testing.assert_allclose(_sign_many(x * scale, scale), _sign_many(x), atol=1e-15)
        np.testing.assert_array_equal(
            smooth_sign_array(x * scale, scale), _sign_many(x * scale, scale)
        )
        assert smooth_sign(1.0001 * WIDTH * scale, scale) == 1.0
