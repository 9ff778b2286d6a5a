"""Repetitions of one NC program in one record: found, and cut into runs of their own.

A machine's trace often holds the same program run several times, not always equally far
apart (an operator's pause, a tool change: 82.0 and 80.6 s on a real record). The rough period
P is the lag of a peak of the velocity's autocorrelation (the velocity, not the position: the
axis's position offset and the rests between runs carry no shape), normalised by the overlap
r(L) = sum v(t) v(t+L) / sqrt(sum v(t)^2 sum v(t+L)^2) over the overlapping samples, with
r(P) >= MIN_CANDIDATE_CORRELATION and P at least MIN_PERIOD_SHARE of the record, so a program's
own back-and-forth moves inside one run (a shorter lag) are not taken for repetitions. Uneven
spacing smears that peak (0.70 on the real record), so it only proposes P: each repetition is
then found on its own, where the first run's motion (its first TEMPLATE_SHARE of P from the
first motion) matches the velocity best within a quarter period of the last one found plus P,
by the normalised cross-correlation, which must reach MIN_CORRELATION. The repetitions must
account for the record's motion: past the end of the last one's motion (the first run's motion
after its start) the axis moves at most LEFT_OVER_SHARE of the first run's moving time (a
program whose own moves repeat inside one run matched its first 1.8 s 2.4 s later at 0.85).
The cuts go where the axis rests: each boundary is the middle of the rest just before a
repetition's start.
"""

from __future__ import annotations

import numpy as np

from feed_twin.io.measured import MeasuredDataError, MeasuredRun, segment

MIN_CORRELATION = 0.8  # [1] normalised cross-correlation of a repetition with the first run
MIN_CANDIDATE_CORRELATION = 0.3  # [1] autocorrelation peak that proposes a period
MIN_PERIOD_SHARE = 0.2  # a repetition spans at least this share of the record
REST_SPEED_SHARE = 0.01  # below this share of the peak speed the axis rests
TEMPLATE_SHARE = 0.75  # the share of the period whose motion identifies a repetition
SEARCH_SHARE = 0.25  # a repetition starts within this share of the period of where expected
LEFT_OVER_SHARE = 0.25  # motion after the last repetition, as a share of the first run's


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


def _candidate_lags(v: np.ndarray) -> list[int]:
    """The lags [samples] of the autocorrelation's peaks that may be the period, shortest
    first."""
    n = len(v)
    r = _overlap_correlation(v)
    first = int(np.ceil(MIN_PERIOD_SHARE * n))
    last = n // 2 + 1  # at least two repetitions fit
    if last <= first + 2:
        return []
    window = r[first:last]
    peaks = np.flatnonzero(
        (window[1:-1] >= window[:-2])
        & (window[1:-1] > window[2:])
        & (window[1:-1] >= MIN_CANDIDATE_CORRELATION)
    )
    return [first + 1 + int(k) for k in peaks]


def _matches(v: np.ndarray, template: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """The normalised cross-correlation of `template` with v[k : k + len(template)] for
    k = lo .. hi - 1, by FFT."""
    from scipy.signal import fftconvolve

    m = len(template)
    part = v[lo : hi + m - 1]
    cross = fftconvolve(part, template[::-1], mode="valid")
    energy = np.r_[0.0, np.cumsum(part * part)]
    local = energy[m:] - energy[:-m]
    norm = np.sqrt(np.maximum(local, 1e-300) * float(np.dot(template, template)))
    return cross / norm


def find_starts(run: MeasuredRun) -> tuple[list[int], float] | None:
    """(the sample where each repetition's motion starts, the least match of a repetition
    with the first run), None if the record holds no repetition (module docstring)."""
    v = _signal(run)
    speed = np.abs(v)
    if not speed.max() > 0.0:
        return None
    first_motion = int(np.argmax(speed >= REST_SPEED_SHARE * float(speed.max())))
    for lag in _candidate_lags(v):
        m = int(TEMPLATE_SHARE * lag)
        template = v[first_motion : first_motion + m]
        starts, least = [first_motion], 1.0
        while True:
            expected = starts[-1] + lag
            lo = max(starts[-1] + m, expected - int(SEARCH_SHARE * lag))
            hi = min(len(v) - m + 1, expected + int(SEARCH_SHARE * lag) + 1)
            if hi <= lo:
                break
            match = _matches(v, template, lo, hi)
            k = int(np.argmax(match))
            if match[k] < MIN_CORRELATION:
                break
            starts.append(lo + k)
            least = min(least, float(match[k]))
        if len(starts) > 1 and _accounted(speed >= REST_SPEED_SHARE * speed.max(), starts):
            return starts, least
    return None


def _accounted(moving: np.ndarray, starts: list[int]) -> bool:
    """Whether the repetitions starting at `starts` account for the record's motion (module
    docstring)."""
    first_run = moving[starts[0] : starts[1]]
    span = int(np.flatnonzero(first_run)[-1]) + 1  # the first run's motion, its rest cut off
    left_over = int(np.sum(moving[starts[-1] + span :]))
    return left_over <= LEFT_OVER_SHARE * int(np.sum(first_run))


def find_period(run: MeasuredRun) -> tuple[float, float] | None:
    """(mean period [s], least match with the first run) of the program's repetitions, None
    if it has none."""
    found = find_starts(run)
    if found is None:
        return None
    starts, least = found
    return float(np.mean(np.diff(starts))) * run.sample_period_s, least


def split_repetitions(run: MeasuredRun) -> list[MeasuredRun]:
    """The record cut into its repetitions (a list of one if it has none)."""
    found = find_starts(run)
    if found is None:
        return [run]
    starts, _ = found
    v = np.abs(_signal(run))
    t = run.t_s
    resting = v < REST_SPEED_SHARE * float(v.max())
    period = float(np.mean(np.diff(t[starts])))
    bounds = [t[0]]
    for k in starts[1:]:
        bounds.append(_rest_middle(t, resting, float(t[k]), period))
    bounds.append(t[-1])
    runs = []
    for k in range(len(starts)):
        try:
            part = segment(run, bounds[k], bounds[k + 1])
        except MeasuredDataError:
            continue
        runs.append(part)
    return runs if len(runs) > 1 else [run]


def _rest_middle(t: np.ndarray, resting: np.ndarray, target: float, period: float) -> float:
    """The middle of the rest nearest to a repetition's start `target`, before it (a sample
    later at most) and within a quarter period, else `target`."""
    h = float(t[1] - t[0])
    near = (t >= target - 0.25 * period) & (t <= target + 1.5 * h)
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
