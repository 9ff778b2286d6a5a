"""The rounding of a record printed for display, found from its values and undone where it
would mislead the twin.

A monitoring log prints positions to a fixed step (1 mm, 0.1 mm) or to a number of significant
figures (76.4 mm and 162 mm: 0.1 mm below 100 mm, 1 mm above): `resolution` finds the step
nearly all samples sit on, `decade_steps` each sample's own step where it grows with the value.
A slow move then reads as a staircase (the rounded value stands still between steps while the
axis moves on), which `dequantize` smooths through the midpoints of its steps before it drives
the twin; fed as it is, the twin would stop and go and name a holding friction from it.
"""

from __future__ import annotations

import numpy as np

from feed_twin.analysis.twin import SLOW_COMMAND_S
from feed_twin.io.measured import MeasuredRun

# quanta tried by `resolution`: 1, 2, 5 x 10^k m (or A) from 1e-12 to 0.5
_LADDER = tuple(m * 10.0**k for k in range(-12, 0) for m in (1.0, 2.0, 5.0))
ON_GRID_FRACTION = 0.98  # a quantum holds when this share of the samples are its multiples
ON_GRID_TOL = 1e-3  # [quanta] how close to a multiple counts as on it (float noise)
STAIRCASE_FRACTION = 0.2  # a staircase: this share of the moving samples stand still
MIN_DECADE_VALUES = 10  # distinct values a decade of magnitude needs to show its own step


def resolution(x: np.ndarray) -> float:
    """The step [signal unit] a signal is rounded to: the largest quantum of 1, 2 or 5 x 10^k
    of which nearly all (ON_GRID_FRACTION) of its samples are multiples; 0 for a signal that is
    not rounded to any (a float computation, a fine encoder). Nearly all, not most: a command
    that dwells on whole millimetres keeps its finer step, and a log printed to 3 significant
    figures (0.1 mm below 100 mm, 1 mm above) reads as its finer step."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return 0.0
    found = 0.0
    for q in _LADDER:
        r = x / q
        if np.mean(np.abs(r - np.round(r)) < ON_GRID_TOL) >= ON_GRID_FRACTION:
            found = q
    return found


def decade_steps(x: np.ndarray) -> np.ndarray:
    """Each sample's rounding step [signal unit]: the whole signal's `resolution` q, but a
    coarser step (10 q, 100 q, ...) above the largest magnitude that still shows the finer
    one, where the samples above it sit on that step with at least MIN_DECADE_VALUES distinct
    values (a log printed to a few significant figures: the mill's Y reads 76.4 and 103.8 mm,
    and 104, 105, ... 162 mm above). A dwell at 280 mm is a multiple of 10 mm and says nothing
    of the step: too few values."""
    x = np.asarray(x, dtype=float)
    q = resolution(x)
    steps = np.full(x.shape, q)
    if q <= 0.0:
        return steps
    size = np.abs(x)
    coarse = 10.0 * q
    while True:
        r = x / coarse
        fine = np.abs(r - np.round(r)) >= ON_GRID_TOL
        top = float(np.max(size[fine])) if fine.any() else -1.0
        above = size > top
        if len(np.unique(x[above])) < MIN_DECADE_VALUES:
            return steps
        steps[above] = coarse
        coarse *= 10.0


def position_resolution(raw: MeasuredRun) -> float:
    """[m] The coarsest step of the record's position channels as recorded (0: not rounded):
    where it grows with the value (`decade_steps`), the step of its largest values."""
    return max(
        (float(np.max(decade_steps(raw[n]))) for n in ("pos_cmd_m", "pos_meas_m") if n in raw),
        default=0.0,
    )


def mixed_steps(raw: MeasuredRun) -> str | None:
    """A line on a position channel whose step grows with its value (significant figures): its
    steps and the share of samples at the coarsest; None where every sample has one step."""
    for name in ("pos_cmd_m", "pos_meas_m"):
        if name not in raw:
            continue
        steps = decade_steps(raw[name])
        fine, coarse = float(np.min(steps)), float(np.max(steps))
        if coarse > fine:
            edge = float(np.min(np.abs(raw[name])[steps == coarse]))
            return (
                f"{name}'s step grows with its value (printed to significant figures): "
                f"{length_text(fine)} below {edge * 1e3:.4g} mm, {length_text(coarse)} from there "
                f"({100 * float(np.mean(steps == coarse)):.0f} % of its samples); what the "
                f"record can show is decided at the coarser {length_text(coarse)}"
            )
    return None


def _single(x: np.ndarray, change: np.ndarray, q: float | np.ndarray) -> np.ndarray:
    """Whether each change of `x` (at the indices `change`) is one step of q (a float, or each
    sample's step: the larger of the two levels')."""
    qs = np.broadcast_to(np.asarray(q, dtype=float), x.shape)
    step = np.maximum(qs[change], qs[change - 1])
    return np.abs(np.abs(x[change] - x[change - 1]) - step) < 0.5 * step


def staircase_fraction(x: np.ndarray, q: float | np.ndarray) -> float:
    """Share of the samples inside slow moves that stand still: between two single steps of q
    (a float, or each sample's step) in the same direction, the rounded value holds while the
    axis moves on."""
    if np.max(q) <= 0.0:
        return 0.0
    steps = np.flatnonzero(np.diff(x) != 0.0) + 1
    if len(steps) < 2:
        return 0.0
    d = np.diff(x)[steps - 1]
    single = _single(x, steps, q)
    same = (np.sign(d[1:]) == np.sign(d[:-1])) & single[1:] & single[:-1]
    held = np.sum(np.diff(steps)[same] - 1)
    moving = np.sum(np.diff(steps)[same])
    return float(held / moving) if moving else 0.0


def dequantize(t: np.ndarray, x: np.ndarray, q: float | np.ndarray) -> np.ndarray:
    """A rounded staircase smoothed through the midpoints of its steps.

    A value rounded to q changes when the true value crosses a midpoint between two levels, so
    each single step of q marks a point of the true motion: half-way between the two samples,
    at the mid level. Between two such points in the same direction the axis moved on (linear
    interpolation); a level held between steps of opposite direction, or at the record's ends,
    is a rest and is held. Steps of several q (a fast move) keep their samples."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    change = np.flatnonzero(np.diff(x) != 0.0) + 1
    if len(change) == 0:
        return x.copy()
    d = x[change] - x[change - 1]
    # a staircase step: one q, with the level held for a sample before or after it (a move
    # slower than a step per sample); at a step or more per sample the samples are the motion
    held_before = np.concatenate(([True], np.diff(change) > 1))
    held_after = np.concatenate((np.diff(change) > 1, [True]))
    single = _single(x, change, q) & (held_before | held_after)
    # a step joins the next when both are single steps in the same direction: a slow move
    joined = single[1:] & single[:-1] & (np.sign(d[1:]) == np.sign(d[:-1]))
    knots = [(float(t[0]), float(x[0]))]
    for j, i in enumerate(change):
        if not (j > 0 and joined[j - 1]):  # the level before was held up to this step
            knots.append((float(t[i - 1]), float(x[i - 1])))
        if single[j]:
            knots.append((float(0.5 * (t[i - 1] + t[i])), float(0.5 * (x[i - 1] + x[i]))))
        if not (j + 1 < len(change) and joined[j]):  # the new level is held from here
            knots.append((float(t[i]), float(x[i])))
    knots.append((float(t[-1]), float(x[-1])))
    kt, first = np.unique(np.array([k[0] for k in knots]), return_index=True)
    return np.interp(t, kt, np.array([k[1] for k in knots])[first])


def smooth_staircases(run: MeasuredRun) -> tuple[MeasuredRun, list[str]]:
    """The run with its rounded position channels smoothed (module docstring), and a note for
    each, in a record slower than SLOW_COMMAND_S (whose command the twin interpolates by a
    cubic): staircases through the midpoints of their steps, then the rounding's jitter at the
    Nyquist frequency (steps of 1 and 2 q alternating at 1.5 q per sample) removed by the
    [1 2 1] / 4 filter, which keeps straight moves and rests as they are. Fed as it is, that
    jitter made the twin's effort at the samples swing by a hundred newtons."""
    notes = []
    changed = {}
    slow = run.sample_period_s > SLOW_COMMAND_S
    for name in ("pos_cmd_m", "pos_meas_m"):
        if name not in run:
            continue
        x = run[name]
        q = decade_steps(x)
        if np.max(q) <= 0.0 or not slow:
            continue
        share = staircase_fraction(x, q)
        if share >= STAIRCASE_FRACTION:
            x = dequantize(run.t_s, x, q)
        changed[name] = _binomial(x)
        fine, coarse = float(np.min(q)), float(np.max(q))
        notes.append(
            f"{name} is rounded to {length_text(fine)}"
            + (f" ({length_text(coarse)} where its values are large)" if coarse > fine else "")
            + (
                f" and a staircase ({100 * share:.0f} % of its samples in slow moves stand "
                "still): smoothed through the midpoints of its steps, not fed to the twin as "
                "stop-and-go, and"
                if share >= STAIRCASE_FRACTION
                else ":"
            )
            + " its rounding jitter filtered ([1 2 1] / 4)"
        )
    if not changed:
        return run, notes
    return run.with_signals(**changed), notes


def _binomial(x: np.ndarray) -> np.ndarray:
    """[1 2 1] / 4 over the samples, the ends kept: zero gain at the Nyquist frequency, exact
    on straight lines."""
    y = x.copy()
    y[1:-1] = 0.25 * x[:-2] + 0.5 * x[1:-1] + 0.25 * x[2:]
    return y


def length_text(x: float) -> str:
    """A length [m] in the unit that reads best, to 2 (mm) or 3 significant figures."""
    if x >= 1e-3:
        return f"{x * 1e3:.2g} mm"
    if x >= 1e-6:
        return f"{x * 1e6:.3g} um"
    return f"{x * 1e9:.3g} nm"


__all__ = [
    "decade_steps",
    "dequantize",
    "length_text",
    "mixed_steps",
    "position_resolution",
    "resolution",
    "smooth_staircases",
    "staircase_fraction",
]
