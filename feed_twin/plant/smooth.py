"""The smooth sign function every regularised discontinuity of the plant uses.

    sgn(x) = x / sqrt(1 + x^2)

It has slope 1 at 0 like tanh (so the step-size bounds of `damping_bounds` hold unchanged) and
tends to +/-1 as 1 - 1/(2 x^2). It is chosen over tanh for cost: a square root and a division
instead of an exponential, which matters because the plant evaluates it about ten times per
derivative call (friction, bearing, screw efficiency, three inverter legs) in the hot loop.
"""

from __future__ import annotations

import math

from numba import njit

_SATURATED = 1e8  # beyond this |x|, sgn(x) = +/-1 to double precision; also avoids x*x overflow


@njit(cache=True, inline="always", error_model="numpy")
def smooth_sign(x: float) -> float:
    """x / sqrt(1 + x^2): a smooth, odd sign function with unit slope at 0."""
    if x > _SATURATED:
        return 1.0
    if x < -_SATURATED:
        return -1.0
    d = 1.0 + x * x
    # x * sqrt(d) / d rather than x / sqrt(d): the root and the division run side by side
    # instead of one after the other, and these signs sit on the current loop's critical path
    return (x / d) * math.sqrt(d)
