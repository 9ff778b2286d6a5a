"""Gas spring (counterbalance of a vertical axis): its linear force law as an oscillator with a
closed form, and its stored energy against the kinetic energy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.core.config import ConfigError
from feed_twin.plant.config import load_plant
from feed_twin.sim.engine import Engine

M, F_0, S_0, K = 10.0, 300.0, 0.2, 4000.0  # [kg], [N], [m], [N/m]


def plant(**params):
    values = {"f_0": F_0, "s_0": S_0, "k": K, **params}
    return load_plant(
        {
            "components": [
                {"name": "slide", "type": "Mass", "params": {"m": M}},
                {"name": "spring", "type": "GasSpring", "params": values},
            ],
            "connect": [["slide.flange", "spring.flange"]],
        },
        source="gas.yaml",
    )


def test_slide_on_a_gas_spring_oscillates_about_its_equilibrium():
    # m s'' = f_0 - k (s - s_0): equilibrium s_eq = s_0 + f_0/k, omega = sqrt(k/m)
    s_eq = S_0 + F_0 / K
    amplitude = 0.01
    engine = Engine(plant(), base_period_s=1e-4)
    engine.reset(positions={"slide": s_eq + amplitude})
    n = 5000
    res = engine.advance(n)
    omega = math.sqrt(K / M)
    expected = s_eq + amplitude * np.cos(omega * res.t)
    assert np.max(np.abs(res["slide.s"] - expected)) < 1e-9
    # no loss: kinetic + gas energy stays what it was
    total = res["stored.slide.kinetic"] + res["stored.spring.gas"]
    assert np.max(np.abs(total - total[0])) < 1e-9 * 0.5 * K * amplitude**2
    assert res["spring.force"][0] == pytest.approx(F_0 - K * (s_eq + amplitude - S_0))


def test_gas_spring_parameters_are_checked():
    with pytest.raises(ConfigError, match=r"gas.yaml: plant.spring.f_0 = -1.0: must be > 0"):
        plant(f_0=-1.0)
    with pytest.raises(ConfigError, match=r"gas.yaml: plant.spring.k = -5.0: must be >= 0"):
        plant(k=-5.0)
