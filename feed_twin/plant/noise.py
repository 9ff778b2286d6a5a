"""Seeded, counter-based Gaussian noise for sensors.

A pair of samples is a pure function of (seed, tick, pair): splitmix64 hashes the three into
two uniform numbers and Box-Muller turns them into two independent standard normal values. No
generator state is carried, so a run split into chunks, a batch in parallel threads and one long
run draw exactly the same numbers, bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_TWO_POW_M53 = 1.0 / 9007199254740992.0


@njit(cache=True, error_model="numpy", fastmath={"arcp", "contract"})
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy", fastmath={"arcp", "contract"})
def standard_normal_pair(seed: int, tick: int, pair: int) -> tuple[float, float]:
    """Two independent standard normal samples determined by (seed, tick, pair) alone.

    Box-Muller gives two normals per pair of uniforms; sensors use both (the logarithm, root
    and trigonometry are most of the cost of sampling the phase-current noise every tick).
    """
    key = np.uint64(seed) * _GOLDEN + np.uint64(tick) * _M1 + np.uint64(pair) * _M2
    a = _mix(key + _GOLDEN)
    b = _mix(a + _GOLDEN)
    u1 = ((a >> np.uint64(11)) + np.uint64(1)) * _TWO_POW_M53
    u2 = (b >> np.uint64(11)) * _TWO_POW_M53
    radius = math.sqrt(-2.0 * math.log(u1))
    angle = 2.0 * math.pi * u2
    return radius * math.cos(angle), radius * math.sin(angle)
