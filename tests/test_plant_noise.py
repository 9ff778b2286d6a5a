"""Counter-based sensor noise: standard normal statistics, independence, pure in its arguments."""

import math

import numpy as np
from numba import njit

from feed_twin.plant.noise import standard_normal_pair

N_PAIRS = 100_000


@njit  # no cache: numba would not notice a change of the callee
def _draw(seed: int, n: int, pair: int) -> np.ndarray:
    out = np.empty((n, 2))
    for k in range(n):
        out[k, 0], out[k, 1] = standard_normal_pair(seed, k, pair)
    return out


def test_pairs_are_standard_normal_and_independent():
    z = _draw(7, N_PAIRS, 3)
    n = z.size
    flat = z.ravel()
    # standard errors of the sample moments of n normal samples: mean 1/sqrt(n),
    # variance sqrt(2/n), kurtosis sqrt(24/n); 5 standard errors
    assert abs(flat.mean()) < 5.0 / math.sqrt(n)
    assert abs(flat.var() - 1.0) < 5.0 * math.sqrt(2.0 / n)
    kurtosis = np.mean(flat**4) / flat.var() ** 2
    assert abs(kurtosis - 3.0) < 5.0 * math.sqrt(24.0 / n)
    # tail mass beyond 3 sigma: 2*(1 - Phi(3)) = 0.0026998, binomial standard error
    tail = 0.0026998
    assert abs(np.mean(np.abs(flat) > 3.0) - tail) < 5.0 * math.sqrt(tail / n)
    # the two members of a pair, successive ticks and neighbouring pairs are uncorrelated
    other = _draw(7, N_PAIRS, 4)
    bound = 5.0 / math.sqrt(N_PAIRS)
    assert abs(np.corrcoef(z[:, 0], z[:, 1])[0, 1]) < bound
    assert abs(np.corrcoef(z[:-1, 0], z[1:, 0])[0, 1]) < bound
    assert abs(np.corrcoef(z[:, 0], other[:, 0])[0, 1]) < bound
    # squared values too: the polar method's shared radius must not couple the magnitudes
    assert abs(np.corrcoef(z[:, 0] ** 2, z[:, 1] ** 2)[0, 1]) < bound


def test_a_sample_depends_on_seed_tick_and_pair_alone():
    first = standard_normal_pair(3, 12345, 2)
    assert standard_normal_pair(3, 12345, 2) == first
    assert _draw(3, 12346, 2)[12345].tolist() == list(first)
    assert standard_normal_pair(4, 12345, 2) != first
    assert standard_normal_pair(3, 12346, 2) != first
    assert standard_normal_pair(3, 12345, 3) != first
