"""Alignment, resampling, metrics and residual location on signals with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.analysis.compare import (
    align,
    compute_metrics,
    estimate_time_shift,
    relative_error_pct,
    resample,
    shift_signal,
)
from feed_twin.analysis.locate import locate

H = 1e-3


def _moves(t: np.ndarray) -> np.ndarray:
    """Smooth back-and-forth moves: 0.1 m strokes with reversals."""
    return 0.05 * (1.0 - np.cos(2.0 * math.pi * 0.5 * t)) + 0.01 * np.sin(2.0 * math.pi * 1.3 * t)


@pytest.mark.parametrize("shift_samples", [3.4, -7.25, 0.0, 12.5])
def test_time_shift_recovered_below_one_sample(shift_samples):
    t = H * np.arange(5000)
    ref = _moves(t)
    meas = _moves(t - shift_samples * H)
    shift, corr = estimate_time_shift(t, meas, ref, max_shift_s=0.05)
    # parabolic refinement of a smooth correlation peak: error well below a tenth of a sample
    assert shift == pytest.approx(shift_samples * H, abs=0.05 * H)
    assert corr > 0.99


def test_align_reports_shift_and_offset():
    t = H * np.arange(5000)
    ref = _moves(t)
    meas = _moves(t - 0.004) + 2e-4
    a = align(t, meas, ref, max_shift_s=0.05)
    assert a.time_shift_s == pytest.approx(0.004, abs=5e-5)
    assert a.position_offset_m == pytest.approx(2e-4, abs=1e-6)


def test_constant_signal_cannot_be_aligned():
    t = H * np.arange(500)
    with pytest.raises(ValueError, match="a signal is constant"):
        estimate_time_shift(t, np.ones(500), _moves(t), max_shift_s=0.01)


def test_shift_and_resample_round_trip():
    t = H * np.arange(2000)
    y = np.sin(2 * math.pi * 2.0 * t)
    back = shift_signal(t, shift_signal(t, y, 0.01), -0.01)
    # interior only; the ends are held
    np.testing.assert_allclose(back[20:-20], y[20:-20], atol=(2 * math.pi * 2.0 * H) ** 2)
    fine = H / 4 * np.arange(8000)
    np.testing.assert_allclose(
        resample(t, y, fine)[:7990],
        np.sin(2 * math.pi * 2.0 * fine)[:7990],
        atol=(2 * math.pi * 2.0 * H) ** 2 / 8,
    )


def test_metrics_follow_their_definitions():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    x_sim = x + np.array([0.1, -0.1, 0.1, -0.3])
    f = np.array([10.0, -10.0, 10.0, -10.0])
    m = compute_metrics(x, x_sim, f, 0.9 * f)
    assert m.fe_dev_rms_m == pytest.approx(math.sqrt((3 * 0.01 + 0.09) / 4))
    assert m.fe_dev_max_m == pytest.approx(0.3)
    assert m.pos_rel_err_pct == pytest.approx(100 * math.sqrt(0.12) / math.sqrt(30))
    assert m.effort_rel_err_pct == pytest.approx(10.0)
    assert m.effort_rms == pytest.approx(1.0)
    assert compute_metrics(x, x_sim).effort_rel_err_pct is None


def test_relative_error_of_zero_signal_is_refused():
    with pytest.raises(ValueError, match="the measured signal is all zeros"):
        relative_error_pct(np.zeros(3), np.ones(3))


def test_locate_finds_direction_position_and_screw_phase():
    t = H * np.arange(20000)
    x = _moves(t)
    v = np.gradient(x, H)
    lead = 0.005
    residual = (
        20.0 * np.sign(v)
        + 3.0 * np.cos(2 * math.pi * x / lead)
        + np.random.default_rng(1).normal(0, 0.5, t.size)
    )
    loc = locate(t, residual, x, v, residual_name="force", unit="N", lead_m=lead, pole_pairs=4)
    d = dict(zip(loc.by_direction.labels, loc.by_direction.mean, strict=True))
    # the cosine term averages out over many screw turns: what is left is the Coulomb step
    assert d["forward"] == pytest.approx(20.0, abs=0.5)
    assert d["backward"] == pytest.approx(-20.0, abs=0.5)
    assert loc.by_screw_phase is not None and loc.by_motor_phase is not None
    # screw phase bins centred at 15, 45, ... deg: their first harmonic is the 3 N ripple, reduced
    # by the bin averaging sinc(30/360); the Coulomb steps leak less than 0.5 N into it
    centres = np.radians(np.arange(15.0, 360.0, 30.0))
    phase_mean = np.array(loc.by_screw_phase.mean)
    amplitude = 2.0 / 12.0 * float(np.sum(phase_mean * np.cos(centres)))
    assert amplitude == pytest.approx(3.0 * np.sinc(30 / 360), abs=0.5)
    assert any("moving forward" in line for line in loc.summary())
    by_direction = loc.as_dict()["by_direction"]
    assert isinstance(by_direction, dict)
    assert by_direction["labels"] == ["backward", "standstill", "forward"]
    # the residual has a 20 N square wave at the 0.5 Hz reversal rhythm
    assert min(abs(f - 0.5) for f in loc.spectrum.peaks_hz[:2]) < 0.3
