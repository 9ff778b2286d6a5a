"""1-D profile kernels: closed forms against their definitions, braking bound monotonicity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.gcode.profile import (
    braking_distance,
    braking_reach,
    phase_distance,
    phase_time,
    plan_speeds,
    reach,
)


def test_phase_time_is_the_s_curve_duration():
    A, J = 2.0, 40.0
    # dv >= A^2/J: ramp A/J, constant acceleration, ramp A/J.
    assert phase_time(0.3, A, J, True) == pytest.approx(0.3 / A + A / J, rel=1e-15)
    # dv < A^2/J: triangular acceleration peaking at sqrt(dv*J) < A.
    assert phase_time(0.05, A, J, True) == pytest.approx(2 * math.sqrt(0.05 / J), rel=1e-15)
    assert phase_time(0.3, A, J, False) == pytest.approx(0.15, rel=1e-15)
    assert phase_distance(0.1, 0.3, A, J, True) == pytest.approx(0.2 * (0.1 + 0.05), rel=1e-15)


@pytest.mark.parametrize("jerk", [True, False])
def test_reach_solves_its_equation_in_every_regime(jerk):
    rng = np.random.default_rng(7)
    for _ in range(3000):
        v_to = rng.uniform(0.0, 0.3) * (rng.random() > 0.2)
        L = 10 ** rng.uniform(-7, -1)
        A, J = rng.uniform(0.5, 5.0), rng.uniform(5.0, 500.0)
        v = reach(v_to, L, A, J, jerk, 10.0)
        d = phase_distance(v, v_to, A, J, jerk)
        assert d <= L  # always feasible
        # ... and tight (v - v_to loses digits when the change is tiny against v_to).
        assert d >= L * (1 - 1e-4)


def test_braking_distance_covers_every_lower_target_and_is_monotonic():
    A, J = 2.0, 40.0
    v = 0.06  # v - v/3 < A^2/J: the triangular regime where slowing can beat stopping
    targets = np.linspace(0.0, v, 601)
    exact = np.array([phase_distance(v, x, A, J, True) for x in targets])
    assert exact[200] > exact[0]  # to v/3 needs more room than to rest
    bound = np.array([braking_distance(v, x, A, J, True) for x in targets])
    assert np.all(bound >= exact)
    assert np.all(np.diff(bound) <= 1e-18)
    for x, b in zip(targets[::50], bound[::50], strict=True):
        assert braking_distance(braking_reach(x, b, A, J, True, 1.0), x, A, J, True) <= b


def test_plan_speeds_fit_every_body_and_respect_caps():
    rng = np.random.default_rng(3)
    m = 200
    L = 10 ** rng.uniform(-5, -2, m)
    A = rng.uniform(0.5, 3.0, m)
    J = rng.uniform(10.0, 100.0, m)
    cap = rng.uniform(0.0, 0.3, m + 1)
    cap[-1] = 0.0
    v = plan_speeds(cap, L, A, J, True, 0.0)
    assert v[0] == 0.0 and v[-1] == 0.0
    assert np.all(v <= cap + (np.arange(m + 1) == 0) * 1.0)
    for i in range(m):
        assert phase_distance(v[i], v[i + 1], A[i], J[i], True) <= L[i]
