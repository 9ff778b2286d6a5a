"""The record's own slots searched: the command's delay (the drive's setpoint latency against
the twin's), the delays of the recorded position and effort, the
trace's averaging window and a current-offset ripple (analysis.effects' record effects).

The twin runs once; each value is applied to its outputs (Twin.simulate with `record`). The
delays' first range is +/- DELAY_RECORD_SAMPLES of the record's sample periods, at least the
edit's own grid (+/- 20 base periods: a 1 kHz drive's 1.25 ms was too narrow for a 2 ms lag
between two channels, and a 50 Hz trace's channels drift by tens of milliseconds), searched in
GRID_POINTS steps, widened (doubled, WIDENINGS times at most) while the best value lies at its
edge, then refined to half a base period around the best (the command's delay to
COMMAND_DELAY_STEP of one: it differs by fractions of a tick). A best delay still at the edge is
said (`AT_EDGE` ends the result's message), not passed off as found. The window is one of the
two ways controllers export a trace: each sample taken as it is (one base tick) or the mean
over its sample period (windows in between stood in for the command's reconstruction from its
means: 5 ms on a 20 ms averaged trace). The ripple is linear in the record: least squares.
"""

from __future__ import annotations

import numpy as np

from feed_twin.analysis.fit import FitResult, Measured, SimOutputs, cost_of
from feed_twin.analysis.model_doc import (
    COMMAND_DELAY_SLOT,
    EFFORT_DELAY_SLOT,
    POSITION_DELAY_SLOT,
    RIPPLE_SLOTS,
    TRACE_WINDOW_SLOT,
)
from feed_twin.analysis.twin import Drive, Twin, drive_period
from feed_twin.plant.effect_api import Edit

RECORD_SEARCHED = (
    COMMAND_DELAY_SLOT,
    EFFORT_DELAY_SLOT,
    POSITION_DELAY_SLOT,
    TRACE_WINDOW_SLOT,
    RIPPLE_SLOTS[0],
)
DELAY_RECORD_SAMPLES = 3  # the delays' first range: +/- this many record sample periods
GRID_POINTS = 41  # values per pass
WIDENINGS = 3  # the range is doubled at most this often while the best lies at its edge
AT_EDGE = "at the edge of the range searched"
COMMAND_DELAY_STEP = 0.025  # the command delay's finest step [base periods]


def search(twin: Twin, edit: Edit, drive: Drive, meas: Measured) -> FitResult:
    """The best value of the edit's record slot (module docstring), as a fit result."""
    if edit.own[0].name == RIPPLE_SLOTS[0]:
        return _ripple(twin, drive, meas)
    (param,) = edit.own
    slot = param.name
    current = twin.record_slots(drive)[slot]
    if slot == TRACE_WINDOW_SLOT:
        return _trace_mode(twin, drive, meas, current)
    reach = max(DELAY_RECORD_SAMPLES * drive_period(drive), max(abs(g) for g in edit.grid))
    # a drive's setpoint latency differs from the twin's by any fraction of a tick: at 0.2 m/s
    # an eighth of a 1 ms tick is 25 um of position
    finest = twin.base_period_s * (COMMAND_DELAY_STEP if slot == COMMAND_DELAY_SLOT else 0.5)
    tried: dict[float, tuple[float, SimOutputs]] = {}

    def evaluate(values: np.ndarray) -> None:
        fresh = sorted({float(v) for v in np.round(values / finest) * finest} - set(tried))
        if not fresh:
            return
        out = twin.simulate(drive, twin.nominal[None, :], record=[{slot: v} for v in fresh])
        for row, value in enumerate(fresh):
            tried[value] = (cost_of(meas, out, row), one_row(out, row))

    evaluate(np.array([current]))
    at_edge = False
    lo, values = -reach, np.linspace(-reach, reach, GRID_POINTS)
    for widening in range(WIDENINGS + 1):
        lo = -reach
        values = np.linspace(lo, reach, GRID_POINTS)
        evaluate(values)
        best = min(tried, key=lambda v: tried[v][0])
        at_edge = abs(best) >= reach - 0.5 * finest
        if not at_edge or widening == WIDENINGS:
            break
        reach *= 2.0
    step = float(values[1] - values[0])
    best = min(tried, key=lambda v: tried[v][0])
    k = min(int(np.ceil(step / finest)), GRID_POINTS // 2)
    evaluate(np.clip(best + finest * np.arange(-k, k + 1), lo, reach))
    inside = [v for v in tried if lo - 0.5 * finest <= v <= reach + 0.5 * finest]
    best = min(inside, key=lambda v: tried[v][0])
    cost, out = tried[best]
    span = f"[{-reach * 1e3:.4g}, {reach * 1e3:.4g}] ms"
    message = f"searched {len(tried)} values of {slot} over {span}"
    if at_edge:
        message += f"; the best, {best * 1e3:.4g} ms, lies {AT_EDGE}"
    return FitResult(
        values={slot: best},
        cost_initial=tried[float(np.round(current / finest) * finest)][0],
        cost=cost,
        converged=bool(np.isfinite(cost)),
        message=message,
        evaluations=len(tried),
        outputs=out,
    )


def _trace_mode(twin: Twin, drive: Drive, meas: Measured, current: float) -> FitResult:
    """The trace's window: one base tick (each sample taken as it is) or its sample period
    (each the mean over it), the two ways controllers export a trace; the command a mean over
    the same window (Twin._inputs)."""
    h = twin.base_period_s
    values = sorted({h, drive_period(drive), current})
    rows = [{TRACE_WINDOW_SLOT: v} for v in values]
    out = twin.simulate(drive, twin.nominal[None, :], record=rows)
    costs = [cost_of(meas, out, row) for row in range(len(values))]
    best = int(np.argmin(costs))
    return FitResult(
        values={TRACE_WINDOW_SLOT: values[best]},
        cost_initial=costs[values.index(current)],
        cost=costs[best],
        converged=bool(np.isfinite(costs[best])),
        message=f"tried the trace sampled and averaged over its period ({len(values)} values)",
        evaluations=len(values),
        outputs=one_row(out, best),
    )


def _ripple(twin: Twin, drive: Drive, meas: Measured) -> FitResult:
    """The current-offset ripple's sin and cos amplitudes (RIPPLE_SLOTS): linear in the
    recorded effort, so the twin runs once and the ripple's unit responses through the trace
    are fitted to the effort by least squares on the fit's samples."""
    base = twin.record_slots(drive)
    current: dict[str, float] = {k: base[k] for k in RIPPLE_SLOTS}
    units: list[dict[str, float]] = [
        {k: float(k == unit) for k in RIPPLE_SLOTS} for unit in RIPPLE_SLOTS
    ]
    zero: dict[str, float] = dict.fromkeys(RIPPLE_SLOTS, 0.0)
    out = twin.simulate(drive, twin.nominal[None, :], record=[zero, *units, current])
    assert out.effort is not None and meas.effort is not None
    on = slice(meas.start, None, meas.stride)
    Z = np.column_stack([out.effort[k + 1][on] - out.effort[0][on] for k in range(2)])
    coef, *_ = np.linalg.lstsq(Z, (meas.effort - out.effort[0])[on], rcond=None)
    best: dict[str, float] = {k: float(v) for k, v in zip(RIPPLE_SLOTS, coef, strict=True)}
    fitted = twin.simulate(drive, twin.nominal[None, :], record=[best])
    cost = cost_of(meas, fitted)
    return FitResult(
        values=best,
        cost_initial=cost_of(meas, out, 3),
        cost=cost,
        converged=bool(np.isfinite(cost)),
        message="the ripple's amplitudes by linear least squares",
        evaluations=2,
        outputs=fitted,
    )


def one_row(out: SimOutputs, row: int) -> SimOutputs:
    return SimOutputs(
        x_m=out.x_m[row : row + 1],
        effort=None if out.effort is None else out.effort[row : row + 1],
        ok=out.ok[row : row + 1],
        voltage_q=None if out.voltage_q is None else out.voltage_q[row : row + 1],
    )
