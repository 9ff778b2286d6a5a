"""1-D profile kernels (trapezoids, the raw plan's pieces): closed forms against definitions."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.gcode.profile import phase_distance, phase_time, plan_speeds, reach


def test_phase_time_is_the_trapezoid_ramp():
    assert phase_time(0.3, 2.0) == pytest.approx(0.15, rel=1e-15)
    assert phase_time(-0.1, 2.0) == 0.0
    assert phase_distance(0.1, 0.3, 2.0) == pytest.approx(0.1 * (0.1 + 0.3) / 2.0 * 2.0 / 2.0)


def test_reach_solves_its_equation():
    rng = np.random.default_rng(7)
    for _ in range(3000):
        v_to = rng.uniform(0.0, 0.3) * (rng.random() > 0.2)
        L = 10 ** rng.uniform(-7, -1)
        A = rng.uniform(0.5, 5.0)
        v = reach(v_to, L, A, 10.0)
        d = phase_distance(v, v_to, A)
        assert d <= L  # always feasible
        # ... and tight (v - v_to loses digits when the change is tiny against v_to).
        assert d >= L * (1 - 1e-4)
        assert v * v - v_to * v_to == pytest.approx(2.0 * A * L, rel=1e-4)


def test_plan_speeds_fit_every_body_and_respect_caps():
    rng = np.random.default_rng(3)
    m = 200
    L = 10 ** rng.uniform(-5, -2, m)
    A = rng.uniform(0.5, 3.0, m)
    cap = rng.uniform(0.0, 0.3, m + 1)
    cap[-1] = 0.0
    v = plan_speeds(cap, L, A, 0.0)
    assert v[0] == 0.0 and v[-1] == 0.0
    assert np.all(v <= cap + (np.arange(m + 1) == 0) * 1.0)
    for i in range(m):
        assert phase_distance(v[i], v[i + 1], A[i]) <= L[i]
