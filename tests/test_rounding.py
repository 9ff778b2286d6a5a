"""A record whose step grows with its value (printed to significant figures): each sample's
step, the line that says so, and the coarser step the record's visibility is decided at."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.rounding import (
    decade_steps,
    mixed_steps,
    position_resolution,
    smooth_staircases,
)
from feed_twin.io.measured import load_measured

MILL = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "umich_mill"


def _significant(x_m: np.ndarray, figures: int) -> np.ndarray:
    """Values [m] printed in mm to `figures` significant figures, read back in m."""
    mm = x_m * 1e3
    return np.array([float(f"{v:.{figures}g}") for v in mm]) * 1e-3


def test_three_significant_figures_step_tenfold_at_100_mm():
    x = _significant(np.linspace(0.05, 0.18, 600), 3)
    steps = decade_steps(x)
    assert np.all(steps[x < 0.0999] == pytest.approx(1e-4))
    assert np.all(steps[x >= 0.1] == pytest.approx(1e-3))


def test_a_fixed_step_with_a_dwell_at_a_round_value_is_one_step():
    """0.1 mm all along; the axis rests at 280 mm (a multiple of 10 mm) at the end."""
    x = np.round(np.concatenate((np.linspace(0.05, 0.2731, 500), np.full(200, 0.28))) / 1e-4) * 1e-4
    assert np.all(decade_steps(x) == pytest.approx(1e-4))


def test_the_mill_log_y_says_its_mixed_steps_and_is_decided_at_1_mm():
    raw = load_measured(MILL / "experiment_01.csv", MILL / "y_map.yaml")
    assert position_resolution(raw) == pytest.approx(1e-3)
    line = mixed_steps(raw)
    assert line is not None
    assert line.startswith(
        "pos_cmd_m's step grows with its value (printed to significant figures): 100 um below "
        "104 mm, 1 mm from there ("
    )
    assert line.endswith("what the record can show is decided at the coarser 1 mm")
    _, notes = smooth_staircases(raw)
    # the coarse part's 1 mm steps are a staircase too, not stop-and-go fed to the twin
    assert notes[1].startswith(
        "pos_meas_m is rounded to 100 um (1 mm where its values are large) and a staircase"
    )


def test_the_mill_log_x_has_one_step():
    raw = load_measured(MILL / "experiment_01.csv", MILL / "x_map.yaml")
    assert mixed_steps(raw) is None
    assert position_resolution(raw) == pytest.approx(1e-3)
