"""The compiled kernel against a reference integration (scipy solve_ivp) of the same model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.control.layout import build_cascade
from feed_twin.core import signals as sig
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.engine import Engine
from feed_twin.sim.reference import reference_run


def _emps_move(n: int) -> np.ndarray:
    """A 1 s manoeuvre: out and back with reversals, like the benchmark's moves."""
    t = np.arange(n) * 1e-3
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = 0.05 * (1.0 - np.cos(2.0 * math.pi * t)) + 0.01 * np.sin(
        6.0 * math.pi * t
    )
    return ref


@pytest.mark.slow
def test_kernel_matches_solve_ivp_over_a_one_second_manoeuvre():
    axis = load_axis_config("config/emps.yaml")
    # a fine encoder: a count flipped by a 1e-12 m difference between the integrators would
    # otherwise change the controller output by kp*kv*5e-8 m and hide the integration error
    plant = axis.plant.with_params(encoder={"counts_per_rev": 1_000_000_000})
    axis = type(axis)(**{**axis.__dict__, "plant": plant})
    record = ["table.s", "table.v", "friction.force", "out.effort_cmd"]
    engine = build_engine(axis, record=record)
    n = 1000
    ref = _emps_move(n)
    fast = engine.run(n, ref=ref)
    slow = reference_run(engine, n, ref=ref)
    s_fast, s_ref = fast["table.s"], slow["table.s"]
    assert np.max(np.abs(s_fast - s_ref)) / np.max(np.abs(s_ref)) < 1e-6
    # velocity carries the local RK4 error of the friction reversals (fifth order in the step)
    v_fast, v_ref = fast["table.v"], slow["table.v"]
    assert np.max(np.abs(v_fast - v_ref)) / np.max(np.abs(v_ref)) < 1e-5


@pytest.mark.slow
def test_kernel_matches_solve_ivp_on_the_full_axis():
    """All states of the default axis (PMSM, inverter, five bodies) in closed loop, 20 ms.

    With one sub-step the nut mode (h*omega = 1.2) carries a fixed-step error of a few 1e-6;
    eight sub-steps and sensors without quantisation or noise leave the generated code and the
    loop as the only things compared."""
    axis = load_axis_config("config/axis_default.yaml")
    plant = axis.plant.with_params(
        current_sensor={"noise_std": 0.0, "adc_bits": 24},
        encoder={"counts_per_rev": 2**30},
        scale={"resolution": 1e-13},
    )
    engine = Engine(
        plant,
        base_period_s=axis.engine.base_period_s,
        substeps=8,
        controller=build_cascade(axis.controller),
    )
    n = 320
    h = engine.h
    t = np.arange(n) * h
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_ACC_M_S2] = 2.0
    ref[:, sig.REF_VEL_M_S] = 2.0 * t
    ref[:, sig.REF_POS_M] = t**2
    fast = engine.run(n, ref=ref)
    slow = reference_run(engine, n, ref=ref, rtol=1e-10, atol=1e-12)
    for name in ("table.s", "motor.phi", "nut.s"):
        a, b = fast[name], slow[name]
        assert np.max(np.abs(a - b)) <= 1e-6 * np.max(np.abs(b)), name
    # a current differing by 1e-7 A flips a count of the 24-bit ADC (6e-6 A) now and then, and
    # the PI current loop passes that on: the currents agree to the ADC resolution's effect
    a, b = fast["motor.i_q"], slow["motor.i_q"]
    assert np.max(np.abs(a - b)) <= 1e-4 * np.max(np.abs(b))
