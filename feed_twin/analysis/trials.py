"""Fitting one candidate effect into the model (a step of analysis.rounds).

The candidate's edit is applied to a copy of the model; its own parameters, and those of the
effects found before (they interact with it), are fitted by output-error least squares
(analysis.fit), or, for a searched delay in ticks or a record slot, by a grid search over one
batch of the engine (a sensor delay then refined between whole ticks: `refined`). Parameters
known only to a factor (fitted in the log: a stiffness) start from the best of a common scan
over factors of four either way (`scanned_start`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import partial

import numpy as np
from scipy.optimize import minimize_scalar

from feed_twin.analysis.fit import (
    FitResult,
    FreeParameter,
    Measured,
    SimOutputs,
    cost_of,
    fit,
    profile_cost,
)
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.record_search import RECORD_SEARCHED, one_row, search
from feed_twin.analysis.twin import Drive, Twin
from feed_twin.plant.effect_api import Edit

# common factors a model's log parameters are scanned over before their fit (scanned_start):
# a factor of four either way in steps of sqrt(2)
LOG_SCAN = tuple(2.0 ** (k / 2) for k in range(-4, 5))
# how far inside its lower bound a new stage's parameter is tried (optimum_at_bound), as a
# share of its scale: 0.06 us of a dead time started at 1.25 us
BOUND_STEP = 0.05
# a refined grid value (`refined`) is found to this share of the grid's step: 2.5 us of a drive's
# 0.25 ms tick, 0.5 % of a 2 ms delay
REFINE_TOLERANCE = 0.01


def fit_resumed(
    twin: Twin, drive: Drive, free: list[FreeParameter], meas: Measured, max_evaluations: int
) -> FitResult:
    """Least squares; resumed once from where it stopped if the budget ran out on the way down
    (a friction fit through stick-slip needs more steps than a mass), so that a fit which was
    still improving is not thrown away for its budget alone."""
    result = fit(
        lambda params: twin.simulate(drive, params),
        twin.nominal,
        twin.index,
        free,
        meas,
        max_evaluations=max_evaluations,
    )
    if result.converged or not result.cost < result.cost_initial:
        return result
    if not all(np.isfinite(v) for v in result.values.values()):
        # a log parameter (a stiffness) that ran off to infinity on the way down: no start for
        # a second fit (it raised on the friction drift of the truth machine), and no model
        return result
    resumed = fit(
        lambda params: twin.simulate(drive, params),
        twin.nominal,
        twin.index,
        [dataclasses.replace(p, initial=result.values[p.name]) for p in free],
        meas,
        max_evaluations=max_evaluations,
    )
    return dataclasses.replace(
        resumed,
        cost_initial=result.cost_initial,
        evaluations=result.evaluations + resumed.evaluations,
    )


def try_candidate(
    model: ModelDoc,
    found_free: list[FreeParameter],
    cand: Candidate,
    drive: Drive,
    meas: Measured,
    max_evaluations: int,
) -> tuple[Edit, list[FreeParameter], Twin, FitResult] | str:
    """Add the candidate to the model and fit it (with `found_free`, the parameters of the
    effects found before); returns the edit, the effect's own parameters, the compiled twin and
    the fit, or why it was not fitted."""
    try:
        edit = cand.effect.edit(model, cand)
    except LookupError as exc:
        return f"{cand.name}: cannot be added to this model ({exc}); not fitted"
    doc = model_of(edit.doc)
    # the effects found before interact with the new one (a constant force fitted alone has
    # absorbed part of a Coulomb force found later): their parameters are fitted again with it
    names = {p.name for p in edit.own}
    alone = list(edit.own)
    again = []
    for p in () if edit.grid else found_free:
        if p.name in names:
            continue
        if not doc.has_slot(p.name):
            continue  # the parameter was split or replaced by the new effect
        again.append(dataclasses.replace(p, initial=doc.get(p.name)))
        names.add(p.name)
    own = edit.own + again
    edit = dataclasses.replace(
        edit, own=own, free=own + [p for p in edit.free if p.name not in names]
    )
    twin = Twin.compile(doc)
    if edit.grid:
        return edit, alone, twin, grid_search(twin, edit, drive, meas)
    at_bound = optimum_at_bound(twin, drive, edit, alone, meas)
    if at_bound is not None:
        return edit, alone, twin, at_bound
    simulate = partial(twin.simulate, drive)
    start, scanned = scanned_start(simulate, twin.nominal, twin.index, edit.own, meas)
    result = fit_resumed(twin, drive, start, meas, max_evaluations)
    if scanned is not None:
        cost_initial, sets = scanned
        result = dataclasses.replace(
            result, cost_initial=cost_initial, evaluations=result.evaluations + sets
        )
    return edit, alone, twin, result


def optimum_at_bound(
    twin: Twin, drive: Drive, edit: Edit, alone: list[FreeParameter], meas: Measured
) -> FitResult | None:
    """For an edit that writes a new stage around one parameter whose lower bound is the value
    without it (Edit.restructures: the dead time's electrical stage, 14x the torque source's
    cost per simulation), the fit's result at that bound when the cost rises from there
    inward (BOUND_STEP), the other parameters at their values now; None where it falls, and
    the least squares runs. On the truth machine's clean records the dead time's cost falls
    all the way to 0, and the least squares reached that bound by halving: 12 steps, 24
    simulations of the expanded twin from any start (23-26 from 0.25-2 us), in every round
    that ranked it (its signature explains 6-9 % of a clean record's effort residual: the
    current loop's lag the torque source lacks). Such a result is no finding (it falls back
    to the values without the effect: rounds.no_finding)."""
    if not edit.restructures or len(alone) != 1:
        return None
    (p,) = alone
    values = (p.lower, p.lower + BOUND_STEP * p.scale)
    batch = np.repeat(twin.nominal[None, :], len(values), axis=0)
    for i in twin.index[p.name]:
        batch[:, i] = values
    out = twin.simulate(drive, batch)
    at, inside = (cost_of(meas, out, row) for row in range(len(values)))
    if not at <= inside:
        return None
    return FitResult(
        values={p.name: p.lower}
        | {
            q.name: float(twin.nominal[twin.index[q.name][0]]) for q in edit.own if q.name != p.name
        },
        cost_initial=at,
        cost=at,
        converged=True,
        message=f"the cost rises from {p.name}'s lower bound {p.lower:g} inward",
        evaluations=len(values),
        outputs=one_row(out, 0),
    )


def scanned_start(
    simulate: Callable[[np.ndarray], SimOutputs],
    base: np.ndarray,
    index: dict[str, tuple[int, ...]],
    free: list[FreeParameter],
    meas: Measured,
) -> tuple[list[FreeParameter], tuple[float, int] | None]:
    """The free parameters with the log ones (a stiffness known only to a factor) scaled
    together by the best of LOG_SCAN, from one batch of the engine; and (the cost at the
    initial values, the sets simulated), None where there is no log parameter.

    The least squares starts where the scan is best: near a model's own values the cost of a
    stiffness can be flat or even fall both ways (a reversal's contact dynamics, which the
    stiffness moves, outweigh the load's deflection there), and the fit stopped a few per
    cent from where it began while the truth lay a factor of two softer."""
    logs = [p for p in free if p.log]
    if not logs:
        return free, None
    batch = np.repeat(base[None, :], len(LOG_SCAN), axis=0)
    for p in free:
        factors = np.asarray(LOG_SCAN) if p.log else np.ones(len(LOG_SCAN))
        for i in index[p.name]:
            batch[:, i] = p.initial * factors
    out = simulate(batch)
    costs = np.array([cost_of(meas, out, row) for row in range(len(LOG_SCAN))])
    best = float(LOG_SCAN[int(np.argmin(costs))])
    start = [dataclasses.replace(p, initial=p.initial * best) if p.log else p for p in free]
    return start, (float(costs[LOG_SCAN.index(1.0)]), len(LOG_SCAN))


def grid_search(twin: Twin, edit: Edit, drive: Drive, meas: Measured) -> FitResult:
    """A searched parameter (a delay in ticks, a recorded channel's delay): every grid value
    in one batch, best kept; while the best is the grid's last value and the parameter may go
    further (its `upper`), the grid goes on in its own steps to twice its reach (a truth
    machine's 4 ms feedback delay was fitted as the 2 ms at the edge of a fixed grid), then
    refined between its neighbours where the edit says the parameter takes values between the
    grid's (`refined`). A record slot (analysis.*) changes no simulation: the twin runs once
    and its output is shifted for each value, over a range the record sets
    (analysis.record_search)."""
    if edit.own[0].name in RECORD_SEARCHED:
        return search(twin, edit, drive, meas)
    (param,) = edit.own
    grid = [float(g) for g in edit.grid]
    values, costs, best_row = grid, [], None
    while values:
        batch = np.repeat(twin.nominal[None, :], len(values), axis=0)
        for i in twin.index[param.name]:
            batch[:, i] = values
        out = twin.simulate(drive, batch)
        fresh = [cost_of(meas, out, row) for row in range(len(values))]
        if best_row is None or min(fresh) < min(costs):
            best_row = one_row(out, int(np.argmin(fresh)))
        costs += fresh
        at_edge = int(np.argmin(costs)) == len(costs) - 1 and len(grid) > 1
        step, last = grid[-1] - grid[-2], grid[-1]
        reach = min(param.upper, 2.0 * last) if at_edge and step > 0.0 else last
        values = [float(v) for v in np.arange(last + step, reach + 0.5 * step, step)]
        grid += values
    best = int(np.argmin(costs))
    start = int(np.argmin(np.abs(np.asarray(grid) - param.initial)))
    assert best_row is not None
    found = FitResult(
        values={param.name: grid[best]},
        cost_initial=float(costs[start]),
        cost=float(costs[best]),
        converged=bool(np.isfinite(costs[best])),
        message=f"grid search over {len(grid)} values",
        evaluations=len(grid),
        outputs=best_row,
    )
    if not (edit.refine and found.converged and len(grid) > 1):
        return found
    step = float(np.min(np.diff(np.sort(grid))))
    return refined(twin, drive, meas, param, found, step)


def refined(
    twin: Twin, drive: Drive, meas: Measured, param: FreeParameter, found: FitResult, step: float
) -> FitResult:
    """The grid's best value refined between its neighbours (one grid step either way, within
    the parameter's bounds) by a bounded scalar search (scipy's Brent on a bracket) to
    REFINE_TOLERANCE of a step, one simulation per value; kept where it is better.

    Better by the channels' likelihood with their noise levels unknown (fit.profile_cost), not
    by J under the weights set at the model before the delay. There the position's weight is
    the delay's own residual (112 um RMS for the truth machine's 1.125 ms feedback delay, 4.5
    ticks), and the effort channel decided alone: the twin's effort cannot follow the
    truth's lightly damped axial ring (233 Hz, zeta 0.003 with that delay, about 1 Hz apart
    from the twin's, so out of phase within a few tenths of a second), the loop damps that
    ring more at a shorter delay, and J preferred the twin's ring small: 4.197 ticks, where
    the position, 0.25 um RMS at 4.5 ticks against 2.5 um at 4.4, says 4.5 (blind_truth's
    4 / 1 / 2 ms read 3.92 / 0.944 / 1.925 ms; docs/diagnose.md). The grid's whole ticks are
    ranked by J as before.

    Not a parabola through the grid's best point and its neighbours: a sensor delay's cost has
    a kink at every whole tick (the interpolation weights are piecewise linear in the delay)
    and is far from a parabola between them; the bounded search found the minimum of a scan
    of the two ticks around the best on the truth machine's delays."""
    name = param.name
    centre = found.values[name]
    lo, hi = max(centre - step, param.lower), min(centre + step, param.upper)
    if not hi > lo:
        return found
    tried: dict[float, tuple[float, SimOutputs]] = {}

    def cost(value: float) -> float:
        batch = twin.nominal[None, :].copy()
        for i in twin.index[name]:
            batch[:, i] = value
        out = twin.simulate(drive, batch)
        tried[float(value)] = (profile_cost(meas, out, 0), one_row(out, 0))
        return tried[float(value)][0]

    minimize_scalar(
        cost, bounds=(lo, hi), method="bounded", options={"xatol": REFINE_TOLERANCE * step}
    )
    evaluations = found.evaluations + len(tried)
    value = min(tried, key=lambda v: tried[v][0])
    best, outputs = tried[value]
    if not best < profile_cost(meas, found.outputs, 0):
        return dataclasses.replace(found, evaluations=evaluations)
    return dataclasses.replace(
        found,
        values={name: value},
        cost=cost_of(meas, outputs, 0),
        message=f"{found.message}, refined to {value:.4g} in {len(tried)} more",
        evaluations=evaluations,
        outputs=outputs,
    )
