"""Counter-based sensor noise: exact standard normal statistics, independence, pure arguments."""

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from feed_twin.plant import noise
from feed_twin.plant.noise import standard_normal

N_TICKS = 200_000


@njit  # no cache: numba would not notice a change of the callee
def _draw(seed: int, n: int, channel: int) -> np.ndarray:
    out = np.empty(n)
    for k in range(n):
        out[k] = standard_normal(seed, k, channel)
    return out


def test_ziggurat_strips_have_equal_area_and_close_at_the_top():
    x, f = noise.X_EDGE, noise.F_EDGE
    # strip i >= 1: rectangle [0, x_i] x [f(x_i), f(x_{i+1})]; the recurrence builds 1..126,
    # the top strip (up to f(0) = 1) must come out with the same area V: that is what R is for
    areas = x[1:-1] * (f[2:] - f[1:-1])
    np.testing.assert_allclose(areas, noise.V, rtol=1e-12)
    # strip 0: the rectangle under f(R) plus the tail beyond R
    tail = math.sqrt(math.pi / 2.0) * math.erfc(noise.R / math.sqrt(2.0))
    assert noise.R * f[1] + tail == pytest.approx(noise.V, rel=1e-12)
    assert abs(noise.R - 3.442619855899) < 1e-11  # Marsaglia and Tsang's value
    assert x[0] * f[1] == pytest.approx(noise.V, rel=1e-12)


def test_samples_are_standard_normal_and_independent():
    z = _draw(7, N_TICKS, 3)
    n = z.size
    # standard errors of the sample moments of n normal samples: mean 1/sqrt(n),
    # variance sqrt(2/n), kurtosis sqrt(24/n); 5 standard errors
    assert abs(z.mean()) < 5.0 / math.sqrt(n)
    assert abs(z.var() - 1.0) < 5.0 * math.sqrt(2.0 / n)
    kurtosis = np.mean(z**4) / z.var() ** 2
    assert abs(kurtosis - 3.0) < 5.0 * math.sqrt(24.0 / n)
    # the whole distribution, including the wedges between strips: Kolmogorov-Smirnov
    assert stats.kstest(z, "norm").pvalue > 1e-4
    # tail mass beyond 3 sigma and beyond the base strip's edge R (the tail algorithm),
    # binomial standard errors
    for edge in (3.0, noise.R):
        mass = 2.0 * stats.norm.sf(edge)
        assert abs(np.mean(np.abs(z) > edge) - mass) < 5.0 * math.sqrt(mass / n)
    # successive ticks and neighbouring channels are uncorrelated, in value and in magnitude
    other = _draw(7, N_TICKS, 4)
    bound = 5.0 / math.sqrt(n)
    assert abs(np.corrcoef(z[:-1], z[1:])[0, 1]) < bound
    assert abs(np.corrcoef(z, other)[0, 1]) < bound
    assert abs(np.corrcoef(z**2, other**2)[0, 1]) < bound


def test_a_sample_depends_on_seed_tick_and_channel_alone():
    first = standard_normal(3, 12345, 2)
    assert standard_normal(3, 12345, 2) == first
    assert _draw(3, 12346, 2)[12345] == first
    assert standard_normal(4, 12345, 2) != first
    assert standard_normal(3, 12346, 2) != first
    assert standard_normal(3, 12345, 3) != first
