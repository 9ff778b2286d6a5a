"""Shadow health names a change on windows that can tell effects apart, and keeps that name on a
window that cannot (a one-way cruise at one speed, where every friction-like effect is one
offset), until a window shows another effect."""

from __future__ import annotations

import numpy as np
import pytest
from test_shadow_twin import SHADOW as TWIN_SHADOW

from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.health import WARN, HealthMonitor, PhysicalEffect

T = 1e-3
F_C, F_V = 20.0, 200.0  # [N], [N s/m] the model's guide friction
MASS = 95.0  # [kg]
RAMP_S = 0.1  # [s] cosine speed ramps
# the EMPS shadow's settings on 1 s windows; a 20 N change warns (the noise is 0.05 N)
SHADOW = TWIN_SHADOW | {
    "window_s": 1.0,
    "baseline_s": 2.0,
    "effort_dev_rms_warn": 1.0,
    "effort_dev_rms_error": 100.0,
}
BACK_AND_FORTH = [(0.4, 0.05), (0.1, 0.0), (0.4, -0.05), (0.1, 0.0)]  # (hold [s], v [m/s])


def speeds(legs: list[tuple[float, float]]) -> np.ndarray:
    """v [m/s] sampled at T: each leg ramps (cosine, RAMP_S) to its speed and holds it."""
    v, out = 0.0, []
    for hold, target in legs:
        ramp = np.arange(1, round(RAMP_S / T) + 1) * T / RAMP_S
        out += list(v + (target - v) * 0.5 * (1.0 - np.cos(np.pi * ramp)))
        out += [target] * round(hold / T)
        v = target
    return np.array(out)


def health_rows(v: np.ndarray, change: np.ndarray) -> np.ndarray:
    """Residual rows (HealthMonitor.COLUMNS) of a machine whose effort exceeds the twin's by
    `change` [N] (function of v) plus 0.05 N of noise."""
    t = T * np.arange(len(v))
    x = 0.1 + np.cumsum(v) * T
    a = np.gradient(v, T)
    twin = MASS * a + F_V * v + F_C * np.tanh(v / 1e-3)
    noise = 0.05 * np.random.default_rng(5).standard_normal(len(t))
    return np.column_stack([t, x, np.zeros_like(t), change + noise, twin])


def judged(v: np.ndarray, change: np.ndarray) -> list:
    physical = tuple(
        PhysicalEffect(effect=e, regressor=r, parameter=p, unit=u, nominal=n, per_effort=1.0)
        for e, r, p, u, n in (
            ("coulomb_friction", "sign_v", "plant.friction.F_c", "N", F_C),
            ("viscous_friction", "v", "plant.friction.F_v", "N s/m", F_V),
        )
    )
    health = HealthMonitor(
        load_shadow_config({"shadow": SHADOW}, source="test"), physical=physical,
        effort_unit="N", lead_m=None, pole_pairs=None, travel_m=0.3,
    )  # fmt: skip
    rows = health_rows(v, change)
    return health.update(rows, valid=np.ones(len(rows), dtype=bool))


def test_a_one_way_cruise_keeps_the_friction_a_reversing_window_named():
    v = speeds(BACK_AND_FORTH * 4 + [(2.8, 0.05)])
    reversing_end = 4.0 + 4 * RAMP_S  # [s] the last reversal's end
    worn = (np.arange(len(v)) * T >= 2.0) & (np.abs(v) > 0.0)
    verdicts = [v for v in judged(v, np.where(worn, F_C * np.sign(v), 0.0)) if v.level == WARN]
    cruise = [x for x in verdicts if x.t_s - 1.0 > reversing_end]
    assert len(cruise) >= 2
    for verdict in verdicts[2:]:  # the first windows straddle the change
        assert verdict.effect == "coulomb_friction", verdict.message
        assert verdict.relative_change == pytest.approx(1.0, abs=0.05), verdict.message
    # on the cruise, a viscous change of the same force fits as well: said, not named
    assert any("this window alone cannot tell it from" in x.message for x in cruise)


def test_a_window_that_tells_another_effect_apart_renames_it():
    legs = [(0.3, 0.02), (0.1, 0.1), (0.1, 0.0), (0.3, -0.02), (0.1, -0.1), (0.1, 0.0)]
    v = speeds(BACK_AND_FORTH * 4 + legs * 6)
    t = np.arange(len(v)) * T
    coulomb = (t >= 2.0) & (t < 4.4)
    change = np.where(coulomb, F_C * np.sign(v), 0.0) + np.where(t >= 4.4, F_V * v, 0.0)
    verdicts = [x for x in judged(v, change) if x.level == WARN]
    assert any(x.effect == "coulomb_friction" for x in verdicts if x.t_s < 4.4)
    late = [x for x in verdicts if x.t_s - 1.0 >= 4.4]
    assert late and all(x.effect == "viscous_friction" for x in late), late[-1].message
    for verdict in late:
        assert verdict.relative_change == pytest.approx(1.0, abs=0.05), verdict.message
