"""Seeded, counter-based Gaussian noise for sensors.

A sample is a pure function of (seed, tick, channel): splitmix64 hashes the three (plus an
attempt counter) into 64 random bits, and the ziggurat method of Marsaglia and Tsang (2000,
J. Stat. Softw. 5(8)) turns them into one standard normal value. The density
f(x) = exp(-x^2/2) is covered by LAYERS strips of equal area V: strip i >= 1 is the rectangle
[0, X[i]] x [f(X[i]), f(X[i+1])] (X decreasing to X[LAYERS] = 0), strip 0 is [0, R] x [0, f(R)]
plus the tail x > R, drawn as if it were a rectangle of width X[0] = V / f(R). One hash gives
the strip (7 bits), the sign (1 bit) and a uniform u (53 bits); z = u X[i] is returned at once
when it lies below the next strip (z < X[i+1]; about 99 % of draws). Otherwise the point is
tested against the curve (a second hash for its height) or, in strip 0 beyond R, drawn from the
tail by Marsaglia's exact method (x = R + a with a = -ln(u1)/R, accepted when -2 ln(u2) > a^2).
Rejected points restart with the next attempt counter. The method is exact: the only
approximations are the double-precision tables.

No generator state is carried, so a run split into chunks, a batch in parallel threads and one
long run draw exactly the same numbers, bit for bit. Cost: one hash, one table lookup and one
product per sample in the common case, where the polar method needed a logarithm, a root and a
division per pair.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray

LAYERS = 128

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_TWO_POW_M53 = 1.0 / 9007199254740992.0


def _strip_area(r: float) -> float:
    """Area of the base strip with edge r: the rectangle under f(r) plus the tail beyond r."""
    return r * math.exp(-0.5 * r * r) + math.sqrt(0.5 * math.pi) * math.erfc(r / math.sqrt(2.0))


def _top_residual(r: float) -> float:
    """f at the lower edge of the top strip minus 1 when every strip has the base's area:
    zero for the right r, positive when r is too small (the strips overshoot f(0) = 1)."""
    v = _strip_area(r)
    x = r
    for _ in range(LAYERS - 2):
        y = v / x + math.exp(-0.5 * x * x)
        if y >= 1.0:
            return 1.0
        x = math.sqrt(-2.0 * math.log(y))
    return v / x + math.exp(-0.5 * x * x) - 1.0


def _solve_r() -> float:
    """The base edge R (about 3.4426 for 128 strips, Marsaglia and Tsang's value), by bisection
    to double precision."""
    lo, hi = 3.0, 4.0
    while True:
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            return hi
        if _top_residual(mid) > 0.0:
            lo = mid
        else:
            hi = mid


R = _solve_r()  # right edge of the base strip
V = _strip_area(R)  # area of every strip under exp(-x^2/2)


def _tables() -> tuple[FloatArray, FloatArray]:
    """(X, F): strip edges X[0..LAYERS] and F = exp(-X^2/2), by the recurrence
    X[i+1] = f^-1(V / X[i] + f(X[i]))."""
    x = np.zeros(LAYERS + 1)
    x[0] = V / math.exp(-0.5 * R * R)
    x[1] = R
    for i in range(1, LAYERS - 1):
        x[i + 1] = math.sqrt(-2.0 * math.log(V / x[i] + math.exp(-0.5 * x[i] * x[i])))
    x[LAYERS] = 0.0
    return x, np.exp(-0.5 * x * x)


X_EDGE, F_EDGE = _tables()


@njit(error_model="numpy", forceinline=True)
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@njit(error_model="numpy", forceinline=True)
def _uniform_open(bits: np.uint64) -> float:
    """A uniform in (0, 1] from the top 53 bits (never 0, so its logarithm is finite)."""
    return ((bits >> np.uint64(11)) + np.uint64(1)) * _TWO_POW_M53


@njit(error_model="numpy", forceinline=False)
def _slow_path(key: np.uint64, layer: int, z: float) -> tuple[float, np.uint64]:
    """The ~1 % of draws outside a strip's inner rectangle: (accepted |x| or -1.0, key)."""
    if layer == 0:
        while True:  # the tail beyond R
            key += _GOLDEN
            a = -math.log(_uniform_open(_mix(key))) / R
            key += _GOLDEN
            b = -math.log(_uniform_open(_mix(key)))
            if b + b > a * a:
                return R + a, key
    key += _GOLDEN
    u = (_mix(key) >> np.uint64(11)) * _TWO_POW_M53
    y = F_EDGE[layer] + u * (F_EDGE[layer + 1] - F_EDGE[layer])
    if y < math.exp(-0.5 * z * z):
        return z, key
    return -1.0, key


@njit(error_model="numpy", forceinline=True)
def standard_normal(seed: int, tick: int, channel: int) -> float:
    """One standard normal sample determined by (seed, tick, channel) alone."""
    key = np.uint64(seed) * _GOLDEN + np.uint64(tick) * _M1 + np.uint64(channel) * _M2
    while True:
        key += _GOLDEN
        bits = _mix(key)
        layer = int(bits & np.uint64(LAYERS - 1))
        sign = 1.0 - 2.0 * float((bits >> np.uint64(7)) & np.uint64(1))
        z = (bits >> np.uint64(11)) * _TWO_POW_M53 * X_EDGE[layer]
        if z < X_EDGE[layer + 1]:
            return sign * z
        z, key = _slow_path(key, layer, z)
        if z >= 0.0:
            return sign * z
