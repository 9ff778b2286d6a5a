"""The statistics of analysis.significance: noise estimates, effective samples, the LR test."""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import pytest

from feed_twin.analysis.significance import compare, effective_samples, sample_noise


def test_sample_noise_of_white_noise_on_a_smooth_motion():
    t = np.linspace(0.0, 10.0, 10001)
    motion = 0.1 * np.sin(2 * math.pi * 0.3 * t) + 0.02 * t**2
    noise = np.random.default_rng(1).normal(0.0, 0.5, t.size)
    # the local cubic leaves the motion out: the estimate is the noise's own deviation
    assert sample_noise(motion + noise) == pytest.approx(0.5, rel=0.05)
    assert sample_noise(motion) < 1e-3


def test_effective_samples_of_white_and_of_filtered_noise():
    rng = np.random.default_rng(2)
    n = 40000
    white = rng.normal(0.0, 1.0, n)
    assert effective_samples(white) == pytest.approx(n, rel=0.1)
    # a 20-sample moving average: the integrated autocorrelation time is 20 (triangle sum)
    ma = np.convolve(rng.normal(0.0, 1.0, n + 19), np.ones(20) / 20, "valid")
    assert effective_samples(ma) == pytest.approx(n / 20.0, rel=0.15)
    # a second-order low-pass (a controller's trace filter): tau is its spectrum at 0 over its
    # variance, 4.7, where the AR(1) value (1 + rho_1)/(1 - rho_1) would say 16
    b, a = [0.0675, 0.135, 0.0675], [1.0, -1.143, 0.4128]  # Butterworth at 0.1 of Nyquist
    from scipy.signal import lfilter

    # without zi, lfilter returns y alone (scipy's annotation says y or (y, zf))
    low = cast(np.ndarray, lfilter(b, a, rng.normal(0.0, 1.0, n)))
    h = cast(np.ndarray, lfilter(b, a, np.r_[1.0, np.zeros(999)]))
    tau_true = np.sum(h) ** 2 / np.sum(h**2)  # spectrum at 0 over variance
    assert effective_samples(low) == pytest.approx(n / tau_true, rel=0.25)


def _channels(rng, effort_scale: float, position_scale: float, n: int = 5000):
    return {
        "effort": effort_scale * rng.normal(0.0, 1.0, n),
        "position": position_scale * rng.normal(0.0, 1.0, n),
    }


def test_an_effect_that_halves_one_channel_is_significant_whatever_the_other_does():
    rng = np.random.default_rng(3)
    before = _channels(rng, 2.0, 1.0)
    # the effort's residual RMS halves; the position channel (filtered noise) does not move
    after = {"effort": 0.5 * before["effort"], "position": before["position"] * 1.001}
    v = compare(before, after, added=1, searched=24)
    assert v.significant
    assert v.explained["effort"] == pytest.approx(0.75, abs=1e-9)
    assert v.best_channel == "effort"


def test_a_chance_improvement_is_not_significant_after_the_search_correction():
    rng = np.random.default_rng(4)
    before = _channels(rng, 1.0, 1.0, n=2000)
    # 0.3 % less residual on one channel: LR about 2000 * 0.003 = 6, p(chi2_2) = 0.05
    after = {"effort": before["effort"] * math.sqrt(0.997), "position": before["position"]}
    alone = compare(before, after, added=2)
    assert not alone.significant  # below MIN_EXPLAINED
    v = compare(before, after, added=2, searched=24)
    assert v.p_value == pytest.approx(min(1.0, 24 * alone.p_value), rel=1e-9)
    assert not v.significant


def test_an_effect_that_trades_one_channel_for_another_is_not_significant():
    rng = np.random.default_rng(5)
    before = _channels(rng, 1.0, 1.0)
    after = {"effort": 0.9 * before["effort"], "position": before["position"] / 0.9}
    v = compare(before, after, added=1)
    # each channel alone would count n ln(1/0.81) = 1054; together they cancel up to the
    # scatter of the two effective sample counts
    assert abs(v.likelihood_ratio) < 0.1 * 5000 * math.log(1 / 0.81)
    assert not v.significant


def test_an_effect_that_worsens_the_channel_it_was_named_in_is_not_significant():
    """A drive gain named on the effort, fitted to explain the position while the effort
    gets 10 % worse (the vertical axis with stiction of benchmarks/real_machine_record.py)."""
    rng = np.random.default_rng(6)
    before = _channels(rng, 1.0, 1.0)
    after = {"effort": before["effort"] * math.sqrt(1.1), "position": 0.6 * before["position"]}
    assert compare(before, after, added=1).significant  # the position alone would carry it
    v = compare(before, after, added=1, own="effort")
    assert v.worsens_own and not v.significant
    assert v.words().endswith("worse in the effort residual it was named in")
    # named in the position, the same fit passes
    assert compare(before, after, added=1, own="position").significant


def test_compare_rejects_a_test_without_parameters():
    with pytest.raises(ValueError, match="added = 0, searched = 1: both must be >= 1"):
        compare({"effort": np.ones(3)}, {"effort": np.ones(3)}, added=0)
