"""DC motor, force source with its current-loop lag, gravity with a counterweight."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.analysis.twin import substeps_needed
from feed_twin.core import signals as sig
from feed_twin.plant.assembly import PlantModel
from feed_twin.plant.config import load_plant
from feed_twin.sim.engine import Engine


def _drive(n: int, effort: float) -> np.ndarray:
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_EFFORT_CMD] = effort
    drive[:, sig.OUT_ENABLED] = 1.0
    return drive


def test_dc_motor_settles_at_the_speed_of_its_voltage_equation():
    R, L, k, J, b, gain, effort = 1.2, 2e-3, 0.08, 2e-4, 1e-4, 2.0, 6.0
    plant = load_plant(
        {
            "components": [
                {
                    "name": "motor",
                    "type": "DcMotor",
                    "params": {
                        "R": R,
                        "L": L,
                        "k": k,
                        "J": J,
                        "T_c": 0.0,
                        "b": b,
                        "omega_reg": 0.01,
                        "gain": gain,
                        "u_max": 24.0,
                        "i_max": 100.0,
                    },
                }
            ],
            "connect": [],
        },
        source="dc",
    )
    n = 8000  # 0.8 s: 22 mechanical time constants J*R/(k^2 + R*b) = 37 ms
    res = Engine(plant, base_period_s=1e-4).run(n, drive=_drive(n, effort))
    u = gain * effort
    # steady state: u = R*i + k*omega and k*i = b*omega
    omega = u * k / (R * b + k * k)
    assert res["motor.omega"][-1] == pytest.approx(omega, rel=1e-6)
    assert res["motor.i"][-1] == pytest.approx(b * omega / k, rel=1e-6)
    assert res["motor.u"][-1] == pytest.approx(u, rel=1e-12)


def _lagged_source(T_lag: float, gain: float) -> PlantModel:
    """A force source with its current loop's lag driving a heavy table (one that keeps its
    speed while the lag is measured)."""
    return load_plant(
        {
            "components": [
                {"name": "table", "type": "Mass", "params": {"m": 1e6}},
                {
                    "name": "drive",
                    "type": "EffortSource",
                    "params": {
                        "domain": "translational",
                        "gain": gain,
                        "T_lag": T_lag,
                        "f_max": 1e6,
                    },
                },
            ],
            "unusual": ["table.m"],
            "connect": [["table.flange", "drive.flange"]],
        },
        source=f"lag {T_lag!r} s",
    )


def test_force_source_follows_its_command_with_the_current_loop_lag():
    T_lag, gain, effort = 2e-3, 35.15, 3.0
    plant = _lagged_source(T_lag, gain)
    n = 100
    res = Engine(plant, base_period_s=1e-4).run(n, drive=_drive(n, effort))
    expected = gain * effort * (1.0 - np.exp(-res.t / T_lag))
    np.testing.assert_allclose(res["drive.effort"], expected, atol=1e-9 * gain * effort)


def test_a_short_lag_gets_the_sub_steps_rk4_needs():
    """The lag's pole 1 / T_lag counts as a fast state: at h = 1 ms a 0.2 ms lag (h / T_lag = 5,
    beyond RK4's 2.5) is refused with one sub-step, and the twin's choice (4: 1.25) follows
    RK4's own closed form on the lag, within 0.3 % of f = g e (1 - exp(-t / T_lag)) (one
    sub-step diverged at tick 6)."""
    T_lag, gain, effort, h = 2e-4, 35.15, 3.0, 1e-3
    plant = _lagged_source(T_lag, gain)
    with pytest.raises(ValueError, match=r"plant.drive: .* fastest rate 5000 1/s is 5, must be"):
        Engine(plant, base_period_s=h)
    nsub = substeps_needed(plant, plant.nominal_params(), h)
    assert nsub == 4
    n = 20
    res = Engine(plant, base_period_s=h, substeps=nsub).run(n, drive=_drive(n, effort))
    # RK4 on this linear lag decays by its stability polynomial R(z) per sub-step, z = -1.25
    z = -h / nsub / T_lag
    r = 1.0 + z + z**2 / 2.0 + z**3 / 6.0 + z**4 / 24.0
    ticks = np.round(res.t / h)
    rk4 = gain * effort * (1.0 - r ** (nsub * ticks))
    np.testing.assert_allclose(res["drive.effort"], rk4, atol=1e-9 * gain * effort)
    exact = gain * effort * (1.0 - np.exp(-res.t / T_lag))
    np.testing.assert_allclose(res["drive.effort"], exact, atol=3e-3 * gain * effort)


@pytest.mark.parametrize("m_cw", [0.0, 40.0])
def test_vertical_axis_falls_with_the_unbalanced_weight(m_cw):
    m, g = 120.0, 9.81
    plant = load_plant(
        {
            "components": [
                {"name": "slide", "type": "Mass", "params": {"m": m}},
                {
                    "name": "gravity",
                    "type": "Gravity",
                    "params": {"m": m, "g": g, "incline_deg": 90.0, "m_counterweight": m_cw},
                },
            ],
            "connect": [["slide.flange", "gravity.flange"]],
        },
        source="vertical",
    )
    res = Engine(plant, base_period_s=1e-3).run(101)
    # the counterweight takes part of the weight and adds its mass to the moving inertia
    a = -(m - m_cw) * g / (m + m_cw)
    np.testing.assert_allclose(res["slide.s"], 0.5 * a * res.t**2, rtol=1e-12, atol=1e-15)
    stored = res["stored.gravity.potential"] + res["stored.slide.kinetic"]
    np.testing.assert_allclose(stored, stored[0], atol=1e-9 * abs(a) * m)
