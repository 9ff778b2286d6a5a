"""The spread between realisations of one truth that differ only in their noise: what of a
record no deterministic twin can reproduce (synthetic.position_spread)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.synthetic import position_spread
from feed_twin.analysis.twin import ModelDoc

ROOT = Path(__file__).resolve().parents[1]
# one reversal and a stop: where the nut crosses its backlash and the table comes to rest
PROGRAM = "G21 G90 G94 G54 G64\nG1 X20 F6000\nG1 X5 F4800\nG4 P0.1\nM30\n"
SEEDS = (0, 1, 2)


def test_a_force_source_truth_records_one_position_whatever_its_noise_seeds():
    """EMPS: the truth's noise is added to the recorded effort after the run, none acts inside
    its loop, so every realisation records the same position (up to the rounding of their
    mean, 1e-18 m)."""
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    spread = position_spread(nominal, {}, seeds=SEEDS, program=PROGRAM)
    assert spread.max() < 1e-15


def test_the_current_adc_noise_is_what_parts_the_realisations_of_a_pmsm_axis():
    """The axis's current ADC (noise 20 mA, steps of 24 mA) acts inside the current loop: the
    realisations part by far more than the scale's 10 nm resolution; with its noise off (the
    rounding alone, deterministic) they record the same position, bit for bit."""
    nominal = ModelDoc.load(ROOT / "config" / "axis_default.yaml")
    noisy = position_spread(nominal, {}, seeds=SEEDS, program=PROGRAM, start_m=0.3)
    assert float(np.sqrt(np.mean(noisy**2))) > 5 * nominal.get("scale.resolution")
    quiet = nominal.set("current_sensor.noise_std", 0.0)
    assert np.all(position_spread(quiet, {}, seeds=SEEDS, program=PROGRAM, start_m=0.3) == 0.0)


def test_a_spread_needs_two_realisations():
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    with pytest.raises(ValueError, match=r"seeds = \(4,\): a spread needs at least two"):
        position_spread(nominal, {}, seeds=(4,), program=PROGRAM)
