"""The guides' Stribeck cut-off (feed_twin.plant.guide_friction.CUT_X) changes no bit of the force:
where it skips the exponential, the law that always evaluates it gives the same double."""

import numpy as np
from numba import njit

from feed_twin.core.smooth import smooth_sign
from feed_twin.plant.expneg import exp_neg
from feed_twin.plant.guide_friction import CUT_RATIO, CUT_X, friction_force


@njit  # the law as it was before the cut-off: the exponential at every velocity
def _uncut(v, F_c_pos, F_c_neg, F_v_pos, F_v_neg, dF_s, v_s, v_reg):
    sgn = smooth_sign(v, v_reg)
    F_c = 0.5 * (F_c_pos + F_c_neg) + 0.5 * (F_c_pos - F_c_neg) * sgn
    F_v = 0.5 * (F_v_pos + F_v_neg) + 0.5 * (F_v_pos - F_v_neg) * sgn
    r2 = (v * (1.0 / v_s)) ** 2
    stribeck = dF_s * exp_neg(r2) if dF_s != 0.0 else 0.0
    return (F_c + stribeck) * sgn + F_v * v


@njit
def _both(v, prm):
    cut = np.empty(v.size)
    full = np.empty(v.size)
    for i in range(v.size):
        cut[i] = friction_force(v[i], *prm)
        full[i] = _uncut(v[i], *prm)
    return cut, full


def _velocities(v_s: float) -> np.ndarray:
    """Both directions, densest around the cut-off |v| = sqrt(CUT_X) v_s."""
    edge = np.sqrt(CUT_X) * v_s
    near = edge * (1.0 + np.linspace(-1e-3, 1e-3, 2001))
    wide = np.geomspace(1e-6, 1e3, 3001) * v_s
    v = np.concatenate([near, wide, [np.nextafter(edge, np.inf), edge]])
    return np.concatenate([v, -v])


def test_cut_off_leaves_every_bit_of_the_force():
    rng = np.random.default_rng(11)
    cases = []
    # the worst case for the bound: F_c just below a power of two (the smallest relative half
    # unit in the last place, 2^-54) and dF_s just below CUT_RATIO * F_c
    for F_c in (np.nextafter(128.0, 0.0), np.nextafter(1.0, 0.0), 120.0, 3.7e-3):
        dF_s = np.nextafter(CUT_RATIO * F_c, 0.0)
        cases.append((F_c, F_c, 400.0, 400.0, dF_s, 2e-3, 1e-4))
    for _ in range(200):  # asymmetric, random scales
        F_pos, F_neg = rng.uniform(1.0, 300.0, 2)
        dF_s = rng.uniform(0.0, CUT_RATIO) * min(F_pos, F_neg)
        v_s = 10.0 ** rng.uniform(-4.0, -1.0)
        v_reg = v_s * 10.0 ** rng.uniform(-3.0, 0.5)
        cases.append((F_pos, F_neg, *rng.uniform(0.0, 900.0, 2), dF_s, v_s, v_reg))
    for prm in cases:
        cut, full = _both(_velocities(prm[5]), prm)
        assert np.array_equal(cut, full), prm


def test_a_stribeck_bump_above_the_ratio_is_still_evaluated():
    # dF_s >= CUT_RATIO * F_c: the term may reach F_c's last bit, so the law keeps it
    F_c, v_s = 1.0, 2e-3
    dF_s = 1e4
    v = np.sqrt(40.0) * v_s * np.array([1.02, 1.05])  # (v/v_s)^2 = 41.6, 44.1 > CUT_X
    cut, full = _both(v, (F_c, F_c, 0.0, 0.0, dF_s, v_s, 1e-5))
    assert np.array_equal(cut, full)
    assert np.all(cut > F_c)  # 1e4 exp(-44.1) = 7e-16: above half the last bit of 1.0
