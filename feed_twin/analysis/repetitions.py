"""Repetitions of one NC program in one record: found, and cut into runs of their own.

A machine's trace often holds the same program run several times. The period P is the lag of
the first strong peak of the velocity's autocorrelation (the velocity, not the position: the
axis's position offset and the rests between runs carry no shape), normalised by the overlap
r(L) = sum v(t) v(t+L) / sqrt(sum v(t)^2 sum v(t+L)^2) over the overlapping samples. A peak
counts if r(P) >= MIN_CORRELATION and P spans at least MIN_PERIOD_SHARE of the record, so a
program's own back-and-forth moves inside one run (a shorter lag) are not taken for
repetitions. The cuts go where the axis rests: each boundary is the middle of the rest nearest
to first motion + k P (or first motion + k P itself if there is no rest there).
"""

from __future__ import annotations

import numpy as np

from feed_twin.io.measured import MeasuredDataError, MeasuredRun, segment

MIN_CORRELATION = 0.8  # [1] normalised autocorrelation of a repetition
MIN_PERIOD_SHARE = 0.2  # a repetition spans at least this share of the record
REST_SPEED_SHARE = 0.01  # below this share of the peak speed the axis rests


def _signal(run: MeasuredRun) -> np.ndarray:
    x = run["pos_cmd_m"] if "pos_cmd_m" in run else run["pos_meas_m"]
    return np.gradient(x, run.sample_period_s)


def _overlap_correlation(v: np.ndarray) -> np.ndarray:
    """r(L) for L = 0 .. n-1 (module docstring), by FFT."""
    n = len(v)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(v, size)
    cross = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n]
    energy = np.cumsum(v * v)
    total = energy[-1]
    head = energy[::-1]  # sum of v^2 over t < n - L (the first n - L samples)
    tail = total - np.r_[0.0, energy[:-1]]  # sum of v^2 over t >= L
    denom = np.sqrt(np.maximum(head * tail, 1e-300))
    return cross / denom


def find_period(run: MeasuredRun) -> tuple[float, float] | None:
    """(period [s], its correlation) of the program's repetitions, None if it has none."""
    v = _signal(run)
    n = len(v)
    r = _overlap_correlation(v)
    first = int(np.ceil(MIN_PERIOD_SHARE * n))
    last = n // 2 + 1  # at least two repetitions fit
    if last <= first + 2:
        return None
    window = r[first:last]
    peaks = np.flatnonzero(
        (window[1:-1] >= window[:-2])
        & (window[1:-1] > window[2:])
        & (window[1:-1] >= MIN_CORRELATION)
    )
    if not len(peaks):
        return None
    lag = first + 1 + int(peaks[0])
    return lag * run.sample_period_s, float(r[lag])


def split_repetitions(run: MeasuredRun) -> list[MeasuredRun]:
    """The record cut into its repetitions (a list of one if it has none)."""
    found = find_period(run)
    if found is None:
        return [run]
    period, _ = found
    v = np.abs(_signal(run))
    t = run.t_s
    resting = v < REST_SPEED_SHARE * float(v.max())
    start = t[int(np.argmax(~resting))]
    count = int(np.floor((t[-1] - start) / period + 0.25))
    bounds = [t[0]]
    for k in range(1, count):
        target = start + k * period
        bounds.append(_rest_middle(t, resting, target, period))
    bounds.append(t[-1])
    runs = []
    for k in range(count):
        try:
            part = segment(run, bounds[k], bounds[k + 1])
        except MeasuredDataError:
            continue
        runs.append(part)
    return runs if len(runs) > 1 else [run]


def _rest_middle(t: np.ndarray, resting: np.ndarray, target: float, period: float) -> float:
    """The middle of the rest nearest to `target` within a quarter period, else `target`."""
    near = np.abs(t - target) <= 0.25 * period
    idx = np.flatnonzero(near & resting)
    if not len(idx):
        return float(target)
    # the rests are runs of consecutive samples: take the one holding the sample nearest target
    nearest = idx[int(np.argmin(np.abs(t[idx] - target)))]
    lo = hi = nearest
    while lo > 0 and resting[lo - 1]:
        lo -= 1
    while hi < len(t) - 1 and resting[hi + 1]:
        hi += 1
    return float(0.5 * (t[lo] + t[hi]))
