"""The inlined sincos against libm: within two units in the last place over the angles a run
reaches, exact at the quadrant points, NaN propagated (the divergence check relies on it)."""

import math

import numpy as np
from numba import njit

from feed_twin.plant.trig import sincos


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
