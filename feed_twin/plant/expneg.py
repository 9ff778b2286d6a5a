"""exp(-x) for x >= 0, written out for the hot loop (the Stribeck term of the friction laws).

    exp_neg(x) = exp(-x) = 2^-n * exp(-r),   n = round(x / ln 2),   r = x - n ln 2,  |r| <= ln2/2

ln 2 is split into a 32-bit head and a tail (Cody and Waite), so n * head is exact for n < 2^21
and r carries no error beyond its last bit. exp(-r) is its Taylor polynomial of degree 13 in
Estrin's form (truncation below 5e-18 relative on |r| <= 0.347); 2^-n comes from a table of
exact powers of two. Within 2 units in the last place of libm (tests/test_plant_smooth.py).
Beyond x = 708 (the last normal double) it returns 0; NaN gives NaN.

Why not math.exp: a libm call in the derivative function makes the compiler spill every live
floating-point register around it, on the hot path or not, and cannot be scheduled with the
rest of the derivative. Written out in IEEE double arithmetic whose fused multiply-adds are
explicit (feed_twin.core.fma, rounded once on every CPU; no fast-math), the result does not
depend on the CPU either, where libm picks an FMA or a non-FMA variant at run time.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from feed_twin.core.fma import fma

X_MAX = 708.0  # exp(-708) = 3.3e-308, the smallest normal range; beyond it the result is 0
_INV_LN2 = 1.44269504088896338700e00
_LN2_HEAD = 6.93147180369123816490e-01  # ln 2 to 32 bits
_LN2_TAIL = 1.90821492927058770002e-10  # ln 2 - head
_ROUND = 6755399441055744.0  # 1.5 * 2^52: x + _ROUND - _ROUND rounds x to an integer
_POW2_NEG = np.array([2.0**-i for i in range(1023)])  # 2^-n, exact, n = 0 .. 1022
# 1/k! for k = 2 .. 13
_F2, _F3, _F4, _F5 = 1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0
_F6, _F7, _F8, _F9 = 1.0 / 720.0, 1.0 / 5040.0, 1.0 / 40320.0, 1.0 / 362880.0
_F10, _F11, _F12, _F13 = 1.0 / 3628800.0, 1.0 / 39916800.0, 1.0 / 479001600.0, 1.0 / 6227020800.0


@njit(cache=True, inline="always", error_model="numpy")
def exp_neg(x: float) -> float:
    """exp(-x) for x >= 0 (and x <= X_MAX; 0 beyond), within 2 ulp."""
    if not x <= X_MAX:
        return 0.0 if x > X_MAX else x  # underflow, or NaN passed on
    n = (x * _INV_LN2 + _ROUND) - _ROUND  # nearest integer
    r = (n * _LN2_HEAD - x) + n * _LN2_TAIL  # -x + n ln 2: exp(-x) = 2^-n exp(r)
    r2 = r * r
    r4 = r2 * r2
    r8 = r4 * r4
    # Estrin: pairs (c_k + c_k+1 r), then powers r^2, r^4, r^8 combine them
    p01 = 1.0 + r
    p23 = fma(_F3, r, _F2)
    p45 = fma(_F5, r, _F4)
    p67 = fma(_F7, r, _F6)
    p89 = fma(_F9, r, _F8)
    p1011 = fma(_F11, r, _F10)
    p1213 = fma(_F13, r, _F12)
    low = fma(r4, fma(r2, p67, p45), fma(r2, p23, p01))
    high = fma(r4, p1213, fma(r2, p1011, p89))
    return fma(r8, high, low) * _POW2_NEG[int(n)]
