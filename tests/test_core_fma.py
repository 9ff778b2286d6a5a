"""The fused multiply-add of the hot loop: rounded once when compiled, a*b + c from Python."""

import math

import numpy as np
from numba import njit

from feed_twin.core.fma import fma


@njit
def _fused(a: float, b: float, c: float) -> float:
    return fma(a, b, c)


def test_compiled_fma_rounds_once():
    # (1 + e)(1 - e) - 1 = -e^2 exactly; the unfused product rounds to 1 and the sum to 0
    e = 2.0**-30
    assert _fused(1.0 + e, 1.0 - e, -1.0) == -(e * e)
    assert (1.0 + e) * (1.0 - e) - 1.0 == 0.0
    assert fma(1.0 + e, 1.0 - e, -1.0) == 0.0  # the Python path: two roundings


def test_compiled_fma_is_the_exact_product_sum_rounded():
    # against exact rational arithmetic on random operands (the error of one rounding only)
    from fractions import Fraction

    rng = np.random.default_rng(3)
    for a, b, c in rng.normal(size=(2000, 3)) * np.array([1.0, 1e3, 1e-2]):
        exact = Fraction(a) * Fraction(b) + Fraction(c)
        assert _fused(a, b, c) == float(exact)  # float() rounds to nearest, like fma


def test_special_values_pass_through():
    assert math.isnan(_fused(math.nan, 1.0, 1.0))
    assert math.isnan(_fused(math.inf, 0.0, 1.0))
    assert _fused(2.0, 3, 1) == 7.0  # integer operands are converted
