"""fit.profile_cost, the likelihood by which a sensor delay is refined between whole ticks
(trials.refined): each channel's noise level unknown and estimated at the model, so
-2 log L = sum_c n_c log(RSS_c / n_c) + const, whatever weights the channels carry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.analysis.fit import Measured, SimOutputs, cost_of, profile_cost

N = 400
RNG = np.random.default_rng(3)
X = RNG.normal(0.0, 1e-6, N)  # [m] measured position
E = RNG.normal(0.0, 1e-2, N)  # [A] measured effort


def _meas(scale_x: float, scale_effort: float, **kw) -> Measured:
    return Measured(x_m=X, effort=E, scale_x=scale_x, scale_effort=scale_effort, **kw)


def _outputs(dx: np.ndarray, de: np.ndarray) -> SimOutputs:
    """Simulations that miss the record by dx [m] and de [A], one row each."""
    return SimOutputs(x_m=X - dx, effort=E - de, ok=np.ones(len(dx), dtype=bool))


def test_it_is_the_sum_over_channels_of_n_log_the_mean_square():
    dx, de = 2e-6 * np.sin(np.arange(N)), 3e-3 * np.cos(np.arange(N))
    meas = _meas(1e-4, 2e-2)
    expected = N * math.log(np.mean((dx / 1e-4) ** 2)) + N * math.log(np.mean((de / 2e-2) ** 2))
    assert profile_cost(meas, _outputs(dx[None, :], de[None, :])) == pytest.approx(expected)


def test_the_channel_weights_shift_it_by_a_constant_and_do_not_change_which_model_wins():
    """A model that takes one channel's residual 50x down beats one that takes the other's
    4 % down, under any weights; J (cost_of) picks by its weights: under those set at the model
    before (position weighed at its 112 um), the 4 % wins."""
    one = np.ones(N)
    dx = np.stack([12.4e-6 * one, 0.25e-6 * one])  # [m] the grid's 4 ticks, then 4.5
    de = np.stack([10.16e-3 * one, 10.61e-3 * one])  # [A]
    out = _outputs(dx, de)
    before = _meas(112e-6, 21.4e-3)
    assert cost_of(before, out, 0) < cost_of(before, out, 1)
    for scale_x, scale_effort in ((112e-6, 21.4e-3), (1e-9, 1.0), (1.0, 1e-6)):
        meas = _meas(scale_x, scale_effort)
        assert profile_cost(meas, out, 1) < profile_cost(meas, out, 0)
        shift = 2.0 * N * math.log(112e-6 / scale_x) + 2.0 * N * math.log(21.4e-3 / scale_effort)
        assert profile_cost(meas, out, 0) == pytest.approx(profile_cost(before, out, 0) + shift)


def test_samples_that_are_no_evidence_do_not_count():
    """An effort weight of 0 (a slow record's accelerations) leaves the sample out of both the
    sum of squares and the count."""
    weight = np.zeros(N)
    weight[: N // 4] = 1.0
    de = np.where(weight > 0.0, 1e-3, 5.0)[None, :]  # 5 A off where it is no evidence
    dx = np.full((1, N), 1e-6)
    meas = _meas(1.0, 1.0, effort_weight=weight)
    expected = N * math.log(1e-12) + (N // 4) * math.log(1e-6)
    assert profile_cost(meas, _outputs(dx, de)) == pytest.approx(expected)


def test_a_diverged_simulation_costs_infinity_and_a_perfect_channel_stays_finite():
    out = _outputs(np.zeros((2, N)), np.full((2, N), 1e-3))
    out = SimOutputs(x_m=out.x_m, effort=out.effort, ok=np.array([True, False]))
    meas = _meas(1.0, 1.0)
    assert math.isfinite(profile_cost(meas, out, 0))
    assert profile_cost(meas, out, 1) == math.inf
