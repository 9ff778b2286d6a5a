"""Period timing of a servo thread from its own clock, against a thread simulated in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.linuxcnc.period_timing import EDGES_MS, period_timing

T = 1e-3  # [s]


def _thread_with_a_stall(stall_ms: float, run_ms: float, n: int = 1000, at: int = 100):
    """Start times of a thread on deadlines t0 + k T that starts period `at` `stall_ms` late and
    then runs the missed periods back to back, `run_ms` each, until it is on its deadlines."""
    t0 = 1234.5  # [s] CLOCK_MONOTONIC is arbitrary
    start = t0 + np.arange(n) * T
    j = 0
    while stall_ms - j * (T * 1e3 - run_ms) > 0:
        start[at + j] += (stall_ms - j * (T * 1e3 - run_ms)) * 1e-3
        j += 1
    return np.arange(n) + 7, start


def test_a_stall_caught_up_back_to_back() -> None:
    tick, start = _thread_with_a_stall(5.5, 0.05)
    timing = period_timing(tick, start, period_s=T)
    assert timing.periods == 1000
    # lateness of period at + j is 5.5 - 0.95 j ms: above one period for j = 0..4
    assert timing.late_periods == 5
    assert timing.lateness_max_ms == pytest.approx(5.5, abs=1e-6)
    assert timing.lateness_p50_ms == pytest.approx(0.0, abs=1e-6)
    # the stalled interval is 6.5 ms, the catch-up ones 0.05 ms
    assert timing.interval_max_ms == pytest.approx(6.5, abs=1e-6)
    assert timing.interval_p50_ms == pytest.approx(1.0, abs=1e-6)
    late = 5.5 - 0.95 * np.arange(6)  # 5.5, 4.55, 3.6, 2.65, 1.7, 0.75 ms
    expected, _ = np.histogram(np.concatenate([np.zeros(994), late]), bins=[*EDGES_MS, np.inf])
    assert timing.histogram == tuple(expected)
    assert sum(timing.histogram) == 1000
    text = timing.format()
    assert text.startswith("servo periods:         1000 ticks, 5 started more than one period late")
    assert "5-10: 1" in text


def test_lost_samples_keep_the_deadlines() -> None:
    tick, start = _thread_with_a_stall(0.0, 0.05)
    keep = np.ones(tick.size, dtype=bool)
    keep[300:310] = False  # ten periods never reached the reader
    timing = period_timing(tick[keep], start[keep], period_s=T)
    assert timing.late_periods == 0
    assert timing.lateness_max_ms == pytest.approx(0.0, abs=1e-6)
    assert timing.interval_max_ms == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    ("tick", "start", "period", "message"),
    [
        ([0, 1], [0.0, 0.001], 0.0, "period_s = 0.0: must be > 0"),
        ([0], [0.0], 1e-3, "1 periods: period timing needs at least 2"),
        ([0, 1, 2], [0.0, 0.001], 1e-3, "tick (3,) and start_s (2,): must be 1-D of one length"),
        ([0, 2, 2], [0.0, 0.001, 0.002], 1e-3, "tick: must increase from period to period"),
    ],
)
def test_bad_input_is_named(tick, start, period, message) -> None:
    with pytest.raises(ValueError) as caught:
        period_timing(np.array(tick), np.array(start), period_s=period)
    assert str(caught.value) == message
