"""The smooth sign function every regularised discontinuity of the plant uses.

    sgn(x / s) = f(u),  u = clip(x / (W s), -1, 1),  f(u) = (15 u - 10 u^3 + 3 u^5) / 8,  W = 15/8

f is the odd quintic with f(1) = 1 and f'(1) = f''(1) = 0, so sgn is twice continuously
differentiable, equal to +/-1 exactly for |x| >= W s, and has its largest slope, 1/s, at x = 0
(W is chosen for that: f'(0) = 15/8 = W), like tanh(x/s) and x/sqrt(s^2 + x^2); so the step-size
bounds of `damping_bounds` hold for it as for those. Modelica's libraries regularise such
switches the same way, with a polynomial over a small band (`Modelica.Fluid.Utilities.regStep`,
a cubic). Unlike x/sqrt(s^2 + x^2), still 3 % short of 1 at x = 4 s, the friction, the bearing
torque and the inverter's dead-time voltage reach their full values just outside the band.

Cost matters: the plant evaluates it six times per derivative call (guide and bearing friction,
screw efficiency, three inverter legs), 24 times per 16 kHz tick, so it is a clamp and five
products, without a square root or a division (docs/performance.md); the polynomial is two fused
multiply-adds (feed_twin.core.fma). `smooth_sign_array`, the analysis code's element-wise form,
is compiled from the same function, so both round alike.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from feed_twin.core.fma import fma

WIDTH = 15.0 / 8.0  # |x| beyond which sgn(x) = +/-1 exactly
_INV_WIDTH = 8.0 / 15.0


@njit(cache=True, inline="always", error_model="numpy")
def smooth_sign(x: float, scale: float) -> float:
    """sgn(x / scale): the quintic (15 u - 10 u^3 + 3 u^5) / 8 of u = clip(8 x / (15 scale), -1, 1).

    `scale` is a parameter (v_reg, i_reg, ...): the compiled loop computes 8 / (15 scale) once.
    """
    # NaN passes through: the divergence check sees it
    u = min(max(x * (_INV_WIDTH / scale), -1.0), 1.0)
    z = u * u
    return u * fma(z, fma(0.375, z, -1.25), 1.875)


# cached: its key is this file, so an edit of smooth_sign recompiles it (an edit of core/fma.py
# would not: clear the cache then)
@njit(cache=True, error_model="numpy")
def _smooth_sign_flat(x: np.ndarray, scale: float) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = smooth_sign(x[i], scale)
    return out


def smooth_sign_array(x: np.ndarray, scale: float) -> np.ndarray:
    """`smooth_sign` element-wise, for the analysis code (the same compiled function)."""
    a = np.asarray(x, dtype=float)
    return _smooth_sign_flat(a.ravel(), float(scale)).reshape(a.shape)
