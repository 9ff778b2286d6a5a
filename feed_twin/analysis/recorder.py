"""Signals as a record holds them: the velocity at its first sample, a channel stamped late, a
trace's mean over its sample period (what analysis.twin does to its outputs to compare them)."""

from __future__ import annotations

import numpy as np

START_FIT_SAMPLES = 7  # samples of the quadratic whose slope at t_0 is the start velocity
START_FIT_S = 0.006  # [s] the longest span of that quadratic
# [m] a start velocity that moves the table less than this over the fit window is a start at
# rest: a record that begins as the axis sets off (a shadow twin's bag) starts exactly at rest
START_TRAVEL_M = 1e-6


def start_velocity(t_s: np.ndarray, x_m: np.ndarray) -> float:
    """Velocity [m/s] at the first sample: the slope at t_0 of a quadratic through the first
    START_FIT_SAMPLES samples (one quantisation step over the window is all it must resolve),
    0 for a record that starts at rest (START_TRAVEL_M)."""
    # over at most START_FIT_S (at least 3 samples): a slow trace's 7 samples span a move
    h = float(t_s[1] - t_s[0]) if len(t_s) > 1 else 1.0
    n = min(START_FIT_SAMPLES, max(3, int(START_FIT_S / h) + 1), len(t_s))
    if n < 3:
        return 0.0
    coef = np.polyfit(t_s[:n] - t_s[0], x_m[:n] - x_m[0], 2)
    v0 = float(coef[1])
    return v0 if abs(v0) * (t_s[n - 1] - t_s[0]) > START_TRAVEL_M else 0.0


def delayed(rows: np.ndarray, t_s: np.ndarray, delay_s: float) -> np.ndarray:
    """Each row as a recorder that stamps it `delay_s` late sees it: y(t - delay), linearly
    interpolated between samples, the first (last) value held outside the record."""
    return np.array([np.interp(t_s - delay_s, t_s, row) for row in np.atleast_2d(rows)])


def window_mean(rows: np.ndarray, dec: int, ticks: int | None = None) -> np.ndarray:
    """Every dec-th column of `rows` replaced by the mean of the `ticks` columns ending there
    (default: dec; fewer at the start), as a trace that averages a fast signal over a window
    (its sample period, or a filter of its own) records it."""
    rows = np.atleast_2d(rows)
    width = dec if ticks is None else ticks
    c = np.concatenate((np.zeros((len(rows), 1)), np.cumsum(rows, axis=1)), axis=1)
    ends = np.arange(0, rows.shape[1], dec)
    starts = np.maximum(ends - width + 1, 0)
    return (c[:, ends + 1] - c[:, starts]) / (ends - starts + 1)


def period_mean(rows: np.ndarray, dec: int, ticks: int | None = None) -> np.ndarray:
    """Every dec-th column of `rows` replaced by the mean over the `ticks` ticks' time ending
    there (default: dec, the record's period), by the trapezoid rule over the ticks + 1
    columns that bound it (fewer at the start; the first column kept): the continuous
    signal's mean over that time whatever the tick, as a trace that averages over its period
    (or a window of its own) records it. window_mean's columns ending there centre the mean
    half a tick late, which differs between two models of one axis at different ticks (a 1 ms
    and a 0.25 ms twin's means of a 150 mm/s move lay 0.375 ms, 56 um, apart) and from a
    machine's trace, which averages over time, not over a twin's ticks."""
    rows = np.atleast_2d(rows)
    width = dec if ticks is None else ticks
    c = np.concatenate((np.zeros((len(rows), 1)), np.cumsum(rows, axis=1)), axis=1)
    ends = np.arange(0, rows.shape[1], dec)
    starts = np.maximum(ends - width, 0)
    span = np.maximum(ends - starts, 1)
    inner = c[:, ends + 1] - c[:, starts] - 0.5 * (rows[:, starts] + rows[:, ends])
    return np.where(ends > starts, inner / span, rows[:, ends])


DEAVERAGE_ITERATIONS = 10  # corrections of the knots (each halves a smooth signal's error)


def deaveraged(
    t_s: np.ndarray, means: np.ndarray, fine_t: np.ndarray, ticks: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(value, rate, second rate) on `fine_t` (ticks h apart) of a smooth signal whose mean over
    the `ticks` ticks' time ending at each stamp t_s[k], (t_s[k] - ticks h, t_s[k]], is
    means[k] (period_mean's law): a cubic spline through knots at the windows' centres, the
    knots corrected until its window means (exact integrals of the spline) are the record's
    (the first window too, which reaches back before the record). Interpolating the means
    themselves smooths the signal twice once the twin's outputs are averaged too (a 50 Hz
    trace's accelerations, and with them the effort, came out flattened: `trace_filter: mean`
    made fits worse)."""
    from scipy.interpolate import CubicSpline

    h = float(fine_t[1] - fine_t[0])
    width = ticks * h
    centres = t_s - 0.5 * width
    means = np.asarray(means, dtype=float)
    knots = means.copy()
    spline = CubicSpline(centres, knots)
    for _ in range(DEAVERAGE_ITERATIONS):
        area = spline.antiderivative()
        knots += means - (area(t_s) - area(t_s - width)) / width
        spline = CubicSpline(centres, knots)
    inside = np.minimum(fine_t, centres[-1])  # held after the last centre
    moving = fine_t <= centres[-1]
    return spline(inside), spline(inside, 1) * moving, spline(inside, 2) * moving
