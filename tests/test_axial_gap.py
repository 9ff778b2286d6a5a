"""The nut's lost motion in the axial compliance (AxialCompliance.gap) and the backlash effect
it carries in a model without a Backlash component (config/truth_nominal.yaml)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from twin_support import simulate_command

from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.plant.axial_compliance import AxialCompliance, axial_force
from feed_twin.plant.backlash import gap_slot

ROOT = Path(__file__).resolve().parents[1]
TRUTH_NOMINAL = ROOT / "config" / "truth_nominal.yaml"
# fixed-free, bearing 4e8 N/m, EA 1.9e8 N, nut at x = 0.3 m: k = 1 / (2.5e-9 + 0.3 / 1.9e8)
ARGS = dict(x=0.3, L=1.0, EA=1.9e8, k_bearing=4e8, k_nut=1e12, fixed_fixed=0.0, x_min=0.01)
K = 1.0 / (1.0 / 4e8 + 0.3 / 1.9e8 + 1.0 / 1e12)


def _force(delta: float, rate: float, gap: float, d: float = 1e4) -> tuple:
    return axial_force.py_func(delta, rate, d=d, gap=gap, **ARGS)


def test_a_gap_is_a_dead_zone_in_series_with_the_spring():
    gap = 20e-6
    f, f_x, k, e, loss = _force(25e-6, 0.0, gap)
    assert k == pytest.approx(K, rel=1e-12)
    assert f == pytest.approx(K * 15e-6, rel=1e-12)  # 25 um less the half gap
    assert e == pytest.approx(0.5 * K * 15e-6**2, rel=1e-12)
    assert _force(-25e-6, 0.0, gap)[0] == pytest.approx(-K * 15e-6, rel=1e-12)
    assert _force(9e-6, 1e-3, gap)[0::3] == (0.0, 0.0)  # inside the gap: no force, no energy
    # a contact pushes, never pulls: the damper of separating faces stops at zero force
    assert _force(11e-6, -1.0, gap)[0] == 0.0
    assert _force(11e-6, 1e-3, gap)[0] == pytest.approx(K * 1e-6 + 10.0, rel=1e-12)
    # the damper's loss is what it adds to the spring force times the rate
    assert _force(11e-6, 1e-3, gap)[4] == pytest.approx(10.0 * 1e-3, rel=1e-9)


def test_no_gap_is_the_plain_spring_to_the_last_bit():
    for delta, rate in ((3e-6, 0.02), (-7e-6, -0.1), (0.0, 0.0)):
        assert _force(delta, rate, 0.0) == (
            K * delta + 1e4 * rate,
            _force(delta, rate, 0.0)[1],
            K,
            0.5 * K * delta * delta,
            1e4 * rate * rate,
        )


def test_the_gap_is_checked():
    params = ModelDoc.load(TRUTH_NOMINAL).component("axial")["params"]
    with pytest.raises(ValueError, match=r"gap = -1e-06: must be >= 0"):
        AxialCompliance(**{**params, "gap": -1e-6})


def test_backlash_is_carried_by_a_declared_axial_gap_only():
    doc = ModelDoc.load(TRUTH_NOMINAL)
    assert gap_slot(doc) == "axial.gap"
    # an axial compliance that does not declare a gap carries none (a screw without a nut
    # interface the user knows of)
    plain = doc.set("axial.gap", 0.0)
    del plain.component("axial")["params"]["gap"]
    with pytest.raises(LookupError, match="nor an AxialCompliance that declares the nut's gap"):
        gap_slot(plain)


def _run(doc: ModelDoc) -> tuple[np.ndarray, np.ndarray]:
    """The twin cruising at +50 mm/s, then at -50 mm/s (smooth 50 ms ramps between):
    (t, table position)."""
    h = doc.base_period()
    t = np.arange(0.0, 1.4, h)

    # speed: 0 -> +v -> -v -> 0, raised-cosine ramps
    def ramp(t0: float) -> np.ndarray:
        u = np.clip((t - t0) / 0.05, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * u)

    v = 0.05 * (ramp(0.1) - 2.0 * ramp(0.6) + ramp(1.2))
    x_cmd = 0.2 + np.cumsum(v) * h
    return t, simulate_command(doc, t, x_cmd).x_m[0]


def test_the_table_cruises_half_the_gap_behind_the_nut():
    """At a steady speed the spring carries the same friction force with and without the gap,
    so the table runs exactly half the gap further behind, on the side it moves away from."""
    doc = ModelDoc.load(TRUTH_NOMINAL)
    gap = 20e-6
    t, x0 = _run(doc)
    _, x1 = _run(doc.set("axial.gap", gap))
    forward = (t > 0.45) & (t < 0.6)
    backward = (t > 1.05) & (t < 1.2)
    assert x0[forward] - x1[forward] == pytest.approx(gap / 2, rel=0.01)
    assert x1[backward] - x0[backward] == pytest.approx(gap / 2, rel=0.01)
