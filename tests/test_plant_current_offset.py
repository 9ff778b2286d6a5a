"""CurrentSensor per-phase offsets: what the ADC reports, and what the Clarke transform keeps."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from feed_twin.control.transforms import clarke, park
from feed_twin.core import signals as sig
from feed_twin.core.config import load_yaml
from feed_twin.plant.sensors import CurrentSensor
from feed_twin.sim.config import build_engine, load_axis_config

OFFSETS = {"offset": 0.05, "offset_a": 0.3, "offset_b": -0.2, "offset_c": 0.1}  # [A]


def _sensor(**changes: float) -> CurrentSensor:
    base = CurrentSensor(
        gain=1.0, offset=0.0, noise_std=0.0, adc_bits=12, range_A=50.0, delay_ticks=0
    )
    return dataclasses.replace(base, **changes)


def test_per_phase_offsets_default_to_zero_and_are_slots():
    s = _sensor()
    assert (s.offset_a, s.offset_b, s.offset_c) == (0.0, 0.0, 0.0)
    slots = _sensor(**OFFSETS).slots()
    assert {k: slots[k] for k in OFFSETS} == OFFSETS


@pytest.mark.parametrize("name", ["offset_a", "offset_b", "offset_c"])
def test_a_non_finite_phase_offset_is_refused_by_name(name):
    with pytest.raises(ValueError, match=f"{name} = nan"):
        _sensor(**{name: math.nan})


def _measured_at_rest(offsets: dict[str, float]) -> np.ndarray:
    data = load_yaml("config/axis_default.yaml")
    for comp in data["plant"]["components"]:
        if comp["type"] == "CurrentSensor":
            comp["params"].update(offsets, noise_std=0.0, delay_ticks=0)
    axis = load_axis_config(data, source="axis_default with phase offsets")
    engine = build_engine(axis, closed_loop=False, record=["meas.i_a_meas_A", "meas.i_b_meas_A",
                                                            "meas.i_c_meas_A"])  # fmt: skip
    n = 20
    drive = np.zeros((n, sig.OUT_SIZE))  # disabled: no phase current flows
    res = engine.run(n, drive=drive)
    return np.array([res[f"meas.i_{x}_meas_A"][-1] for x in "abc"])


def test_each_phase_reads_the_common_plus_its_own_offset_within_half_an_adc_step():
    measured = _measured_at_rest(OFFSETS)
    step = 2.0 * 50.0 / 2**12
    expected = [OFFSETS["offset"] + OFFSETS[f"offset_{x}"] for x in "abc"]
    np.testing.assert_allclose(measured, expected, atol=0.5 * step + 1e-12)


def test_common_offset_cancels_in_clarke_phase_offsets_give_a_q_ripple_at_theta_e():
    """alpha = (2/3)(o_a - (o_b + o_c)/2), beta = (o_b - o_c)/sqrt(3); in the rotating frame the
    q reading is -alpha sin(theta_e) + beta cos(theta_e): amplitude hypot(alpha, beta)."""
    step = 2.0 * 50.0 / 2**12
    common_only = _measured_at_rest({"offset": 0.4})
    alpha0, beta0 = clarke(*common_only)
    assert abs(alpha0) < step and abs(beta0) < step  # only the ADC rounding is left
    alpha, beta = clarke(*_measured_at_rest(OFFSETS))
    o_a, o_b, o_c = (OFFSETS[f"offset_{x}"] for x in "abc")
    assert alpha == pytest.approx((2.0 / 3.0) * (o_a - 0.5 * (o_b + o_c)), abs=step)
    assert beta == pytest.approx((o_b - o_c) / math.sqrt(3.0), abs=step)
    theta = np.linspace(0.0, 2.0 * math.pi, 64)
    i_q = np.array([park(alpha, beta, th)[1] for th in theta])
    assert np.ptp(i_q) / 2.0 == pytest.approx(math.hypot(alpha, beta), rel=1e-3)
