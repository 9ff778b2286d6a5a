"""Seeded, counter-based Gaussian noise for sensors.

A pair of samples is a pure function of (seed, tick, pair): splitmix64 hashes the three into
points (u, v) uniform in the square [-1, 1)^2 until one falls inside the unit circle, and
Marsaglia's polar method turns it into two independent standard normal values,
    (u, v) * sqrt(-2 ln(r2) / r2),   r2 = u^2 + v^2 in (0, 1)
(exact, like Box-Muller, but without the sine and cosine: a logarithm, a root and a division; a
point is accepted with probability pi/4, the n-th attempt hashes its own counter). No generator
state is carried, so a run split into chunks, a batch in parallel threads and one long run draw
exactly the same numbers, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_TWO_POW_M52 = 1.0 / 4503599627370496.0


@njit(cache=True, error_model="numpy")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def standard_normal_pair(seed: int, tick: int, pair: int) -> tuple[float, float]:
    """Two independent standard normal samples determined by (seed, tick, pair) alone.

    The polar method gives two normals per accepted point; sensors use both (the logarithm and
    root are most of the cost of sampling the phase-current noise every tick; Box-Muller's sine
    and cosine cost as much again).
    """
    key = np.uint64(seed) * _GOLDEN + np.uint64(tick) * _M1 + np.uint64(pair) * _M2
    while True:
        key += _GOLDEN
        a = _mix(key)
        key += _GOLDEN
        b = _mix(key)
        # top 53 bits -> [0, 2) -> [-1, 1)
        u = (a >> np.uint64(11)) * _TWO_POW_M52 - 1.0
        v = (b >> np.uint64(11)) * _TWO_POW_M52 - 1.0
        r2 = u * u + v * v
        if 0.0 < r2 < 1.0:
            factor = math.sqrt(-2.0 * math.log(r2) / r2)
            return u * factor, v * factor
