"""How late a servo thread ran, from its own clock: the start time of each period.

LinuxCNC's uspace servo thread sleeps to absolute deadlines t0 + k * T (CLOCK_MONOTONIC). On a
kernel without PREEMPT_RT a period that starts late is caught up: the next ones run back to
back until the thread is on its deadlines again, so the mean rate stays exactly 1/T while single
periods start late. Two figures tell it:

- lateness of period k: start_k - (t0 + k * T), t0 the earliest start the record admits
  (min over k of start_k - k * T: the thread is never early, so the least late period is taken
  as on time). A period is late when its lateness exceeds one period T (its start fell into the
  next period's slot: whatever waited for it, a drive or a fieldbus frame, missed it);
- interval jitter: start_k - start_(k-1) - T, what a reader of consecutive periods sees.

The periods are indexed by their tick count (the `feedtwin_clock` component's), so lost samples
leave gaps without shifting the deadlines. The histogram of lateness has fixed edges in ms
(`EDGES_MS`), so runs compare bin by bin.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

# [ms] bin edges of the lateness histogram; the last bin is open
EDGES_MS = (0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0, 50.0)


@dataclass(frozen=True, kw_only=True)
class PeriodTiming:
    periods: int  # periods the record holds
    period_s: float  # [s] the thread's nominal period T
    lateness_p50_ms: float  # [ms] start - deadline
    lateness_p99_ms: float  # [ms]
    lateness_max_ms: float  # [ms]
    late_periods: int  # periods that started more than one period after their deadline
    interval_p50_ms: float  # [ms] start to start of consecutive periods
    interval_p99_ms: float  # [ms]
    interval_max_ms: float  # [ms]
    histogram: tuple[int, ...]  # periods per lateness bin (EDGES_MS, the last bin open)

    def as_dict(self) -> dict:
        out = asdict(self)
        out["histogram"] = list(self.histogram)
        out["histogram_edges_ms"] = list(EDGES_MS)
        return out

    def format(self) -> str:
        edges = zip(EDGES_MS[:-1], EDGES_MS[1:], self.histogram[:-1], strict=True)
        bins = [f"{low:g}-{high:g}: {n}" for low, high, n in edges]
        bins.append(f">{EDGES_MS[-1]:g}: {self.histogram[-1]}")
        return (
            f"servo periods:         {self.periods} ticks, {self.late_periods} started more than "
            f"one period late; start lateness p50 {self.lateness_p50_ms:.3f} ms, p99 "
            f"{self.lateness_p99_ms:.3f} ms, max {self.lateness_max_ms:.1f} ms; interval p99 "
            f"{self.interval_p99_ms:.3f} ms, max {self.interval_max_ms:.1f} ms\n"
            f"start lateness [ms]:   {', '.join(bins)}"
        )


def period_timing(tick: np.ndarray, start_s: np.ndarray, *, period_s: float) -> PeriodTiming:
    """The timing of the periods `tick` (servo thread's counter) that started at `start_s`
    (CLOCK_MONOTONIC, s) of a thread of period `period_s` (module docstring)."""
    if not period_s > 0:
        raise ValueError(f"period_s = {period_s!r}: must be > 0")
    tick = np.asarray(tick, dtype=np.int64)
    start_s = np.asarray(start_s, dtype=float)
    if tick.shape != start_s.shape or tick.ndim != 1:
        raise ValueError(
            f"tick {tick.shape} and start_s {start_s.shape}: must be 1-D of one length"
        )
    if tick.size < 2:
        raise ValueError(f"{tick.size} periods: period timing needs at least 2")
    if np.any(np.diff(tick) <= 0):
        raise ValueError("tick: must increase from period to period")
    relative = start_s - (tick - tick[0]) * period_s
    lateness_ms = (relative - relative.min()) * 1e3
    interval_ms = np.diff(start_s)[np.diff(tick) == 1] * 1e3
    if interval_ms.size == 0:
        interval_ms = np.array([np.nan])
    counts, _ = np.histogram(lateness_ms, bins=[*EDGES_MS, np.inf])
    return PeriodTiming(
        periods=int(tick.size),
        period_s=period_s,
        lateness_p50_ms=float(np.percentile(lateness_ms, 50)),
        lateness_p99_ms=float(np.percentile(lateness_ms, 99)),
        lateness_max_ms=float(lateness_ms.max()),
        late_periods=int(np.count_nonzero(lateness_ms > period_s * 1e3)),
        interval_p50_ms=float(np.percentile(interval_ms, 50)),
        interval_p99_ms=float(np.percentile(interval_ms, 99)),
        interval_max_ms=float(interval_ms.max()),
        histogram=tuple(int(n) for n in counts),
    )
