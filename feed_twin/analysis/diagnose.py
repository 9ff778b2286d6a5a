"""The discrepancy workflow: compare, locate, name, add and fit, and show the gap shrink.

    measured run + nominal model
      -> simulate the nominal twin on the measured command and known disturbances
      -> align (time shift, position offset) and metrics "before"
      -> locate the residual (direction, speed, position, phases, spectrum)
      -> repeat: rank the effect library on the current residual; for the leading significant
         candidates add the effect to the model and fit its own parameters (and those of the
         effects found before) by simulation-based least squares; keep the candidate that
         removes the most cost per added degree of freedom
      -> re-fit all found effects jointly with the nominal parameters they interact with
      -> metrics "after", optional validation on a second run, report.

Significance: a candidate is fitted only if its signature passed the ranking's statistical test
(partial F-test against the noise left by all signatures, see analysis.effects); the fitted
effect is kept only if the simulation confirms it, removing at least MIN_EXPLAINED of the cost.
A fit that does not converge is reported and its model discarded; the last good model stays.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from feed_twin.analysis.compare import Metrics, align, compute_metrics
from feed_twin.analysis.edits import EDITS, Edit, interacting
from feed_twin.analysis.effects import Motion, motion_from_position
from feed_twin.analysis.fit import (
    FitResult,
    FreeParameter,
    Measured,
    SimOutputs,
    cost_of,
    fit,
)
from feed_twin.analysis.locate import locate
from feed_twin.analysis.ranking import MIN_EXPLAINED, Candidate, evidence, rank
from feed_twin.analysis.report import Diagnosis, FoundEffect, Trace
from feed_twin.analysis.twin import Drive, ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import MeasuredRun

VOLTAGE_Q = "voltage_q_V"  # the canonical signal of the current controller's q-voltage

Progress = Callable[[str], None]


@dataclass(frozen=True, kw_only=True)
class Options:
    max_effects: int = 5  # rounds of add-and-fit at most
    candidates_per_round: int = 3  # significant candidates fitted by simulation per round
    rival_ratio: float = 0.5  # fit a rival only if it explains this share of the leader's part
    max_evaluations: int = 30  # least-squares function evaluations per fit
    fit_samples: int = 6000  # cost samples per channel (the record is strided down to this)

    def __post_init__(self) -> None:
        for name in ("max_effects", "candidates_per_round", "max_evaluations", "fit_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r}: must be a whole number >= 1")
        if not 0.0 < self.rival_ratio <= 1.0:
            raise ValueError(f"rival_ratio = {self.rival_ratio!r}: must lie in (0, 1]")


@dataclass
class _State:
    doc: ModelDoc
    twin: Twin
    outputs: SimOutputs
    cost: float
    found: list[FoundEffect] = field(default_factory=list)
    found_free: list[FreeParameter] = field(default_factory=list)


class _Values(dict):
    """Fitted values read from a model document on demand (for the reported parameters)."""

    def __init__(self, doc: ModelDoc) -> None:
        super().__init__()
        self.doc = doc

    def __missing__(self, name: str) -> float:
        return self.doc.get(name)


def _loop_stiffness(twin: Twin, drive: Drive, out0: SimOutputs) -> float | None:
    """Static stiffness [N/m] of the closed position loop, from the twin itself: the extra
    effort per metre of extra following error when the mass is 20 % heavier (a load the
    loop must carry), fitted over the record. None if the twin has no mass to change."""
    m = twin.doc.mass_slot()
    if m is None or out0.effort is None:
        return None
    p = twin.nominal.copy()
    for i in twin.index[m]:
        p[i] *= 1.2
    out = twin.simulate(drive, p[None, :])
    if not out.ok[0] or out.effort is None:
        return None
    df = out.effort[0] - out0.effort[0]
    dx = out0.x_m[0] - out.x_m[0]
    denom = float(np.dot(dx, dx))
    return abs(float(np.dot(df, dx)) / denom) if denom > 0 else None


def _unit(twin: Twin, cand: Candidate) -> str:
    return {"effort": twin.effort_unit, "voltage": "V"}.get(cand.residual_domain, "m")


def _noop(_: str) -> None:
    pass


def _residuals(run: MeasuredRun, out: SimOutputs, row: int = 0):
    x = run["pos_meas_m"]
    rp = out.x_m[row] - x
    re = None
    name = run.effort_name
    if name is not None and out.effort is not None:
        re = run[name] - out.effort[row]
    return re, rp


def _voltage_residual(run: MeasuredRun, out: SimOutputs, row: int = 0) -> np.ndarray | None:
    """Measured minus twin q-voltage [V] of the current controller, when both have it."""
    if VOLTAGE_Q not in run or out.voltage_q is None:
        return None
    return run[VOLTAGE_Q] - out.voltage_q[row]


def _measured(run: MeasuredRun, out: SimOutputs, stride: int) -> Measured:
    re, rp = _residuals(run, out)
    ru = _voltage_residual(run, out)
    name = run.effort_name
    return Measured(
        x_m=run["pos_meas_m"],
        effort=None if name is None or out.effort is None else run[name],
        scale_x=max(float(np.sqrt(np.mean(rp**2))), 1e-9),
        scale_effort=1.0 if re is None else max(float(np.sqrt(np.mean(re**2))), 1e-9),
        stride=stride,
        voltage_q=None if ru is None else run[VOLTAGE_Q],
        scale_voltage=1.0 if ru is None else max(float(np.sqrt(np.mean(ru**2))), 1e-6),
    )


def _metrics(run: MeasuredRun, out: SimOutputs, row: int = 0) -> Metrics:
    name = run.effort_name
    effort_sim = None if out.effort is None or name is None else out.effort[row]
    has_u = _voltage_residual(run, out, row) is not None
    return compute_metrics(
        run["pos_meas_m"],
        out.x_m[row],
        None if name is None else run[name],
        effort_sim,
        run[VOLTAGE_Q] if has_u else None,
        out.voltage_q[row] if has_u and out.voltage_q is not None else None,
    )


def _trace(label: str, run: MeasuredRun, drive: Drive, out: SimOutputs) -> Trace:
    name = run.effort_name
    has_u = _voltage_residual(run, out) is not None
    return Trace(
        label=label,
        t_s=run.t_s,
        pos_cmd_m=drive.pos_ref_m,
        x_meas_m=run["pos_meas_m"],
        x_sim_m=out.x_m[0],
        effort_meas=None if name is None else run[name],
        effort_sim=None if out.effort is None or name is None else out.effort[0],
        effort_name=name,
        u_q_meas_V=run[VOLTAGE_Q] if has_u else None,
        u_q_sim_V=out.voltage_q[0] if has_u and out.voltage_q is not None else None,
    )


def _try(
    state: _State, cand: Candidate, drive: Drive, meas: Measured, opts: Options
) -> tuple[Edit, Twin, FitResult] | str:
    if cand.name not in EDITS:
        return (
            f"{cand.name}: named by its signature, but the workflow cannot add "
            f"{cand.effect.component} to a model yet; not fitted"
        )
    try:
        edit = EDITS[cand.name](state.doc, cand)
    except LookupError as exc:
        return f"{cand.name}: cannot be added to this model ({exc}); not fitted"
    # the effects found before interact with the new one (a constant force fitted alone has
    # absorbed part of a Coulomb force found later): their parameters are fitted again with it
    names = {p.name for p in edit.own}
    again = []
    for p in () if edit.grid else state.found_free:
        if p.name in names:
            continue
        if not edit.doc.has_slot(p.name):
            continue  # the parameter was split or replaced by the new effect
        again.append(dataclasses.replace(p, initial=edit.doc.get(p.name)))
        names.add(p.name)
    own = edit.own + again
    edit = dataclasses.replace(
        edit, own=own, free=own + [p for p in edit.free if p.name not in names]
    )
    twin = Twin.compile(edit.doc)
    if edit.grid:
        return edit, twin, _grid_search(twin, edit, drive, meas)
    result = fit(
        lambda params: twin.simulate(drive, params),
        twin.nominal,
        twin.index,
        edit.own,
        meas,
        max_evaluations=opts.max_evaluations,
    )
    return edit, twin, result


def _grid_search(twin: Twin, edit: Edit, drive: Drive, meas: Measured) -> FitResult:
    """Whole-number parameter (a delay in ticks): every grid value in one batch, best kept."""
    (param,) = edit.own
    slots = twin.index[param.name]
    batch = np.repeat(twin.nominal[None, :], len(edit.grid), axis=0)
    for i in slots:
        batch[:, i] = edit.grid
    out = twin.simulate(drive, batch)
    costs = np.array([cost_of(meas, out, row) for row in range(len(edit.grid))])
    best = int(np.argmin(costs))
    start = int(np.argmin(np.abs(np.asarray(edit.grid) - param.initial)))
    row = SimOutputs(
        x_m=out.x_m[best : best + 1],
        effort=None if out.effort is None else out.effort[best : best + 1],
        ok=out.ok[best : best + 1],
        voltage_q=None if out.voltage_q is None else out.voltage_q[best : best + 1],
    )
    return FitResult(
        values={param.name: float(edit.grid[best])},
        cost_initial=float(costs[start]),
        cost=float(costs[best]),
        converged=bool(np.isfinite(costs[best])),
        message=f"grid search over {len(edit.grid)} values",
        evaluations=len(edit.grid),
        outputs=row,
    )


def _final_joint(state: _State, drive: Drive, meas: Measured, opts: Options) -> str | None:
    """Re-fit all found effects together with the nominal parameters they interact with.

    Done once, at the end: re-estimating the mass or the viscous coefficient in every round
    would let them absorb the signature of an effect that is found later. If the joint fit
    does not converge or is not better, the effect-by-effect model stays and the note says so.
    """
    free = []
    for p in state.found_free:
        if not state.doc.has_slot(p.name):
            continue  # a tie split by a later effect (Coulomb by asymmetric friction)
        free.append(dataclasses.replace(p, initial=state.doc.get(p.name)))
    names = {p.name for p in free}
    gain = state.doc.gain_slot()
    if gain not in names:
        # with a fitted drive gain the mass and friction would be degenerate (the gain scales
        # every force), so they are re-estimated only when the gain is not
        free += [p for p in interacting(state.doc) if p.name not in names]
    twin = Twin.compile(state.doc)
    joint = fit(
        lambda params: twin.simulate(drive, params),
        twin.nominal,
        twin.index,
        free,
        meas,
        max_evaluations=opts.max_evaluations,
    )
    if not joint.converged or joint.cost > state.cost:
        return (
            f"the joint re-fit of the found effects and the nominal parameters did not "
            f"converge or improve ({joint.message}); kept the effect-by-effect fit"
        )
    doc = state.doc
    for name, value in joint.values.items():
        doc = doc.set(name, value)
    state.doc = doc
    state.twin = Twin.compile(doc)
    state.outputs, state.cost = joint.outputs, joint.cost
    return None


def diagnose(
    run: MeasuredRun,
    nominal: ModelDoc,
    *,
    validate: MeasuredRun | None = None,
    options: Options | None = None,
    progress: Progress = _noop,
    model_path: str = "model.yaml",
) -> tuple[Diagnosis, ModelDoc, Motion]:
    """Run the workflow on `run`; returns the diagnosis, the final model and the motion used."""
    opts = options or Options()
    clock = time.perf_counter()
    timings: dict[str, float] = {}
    notes = list(run.warnings)
    drive = drive_from_run(run)
    progress(f"compiling the nominal model {nominal.source}")
    twin = Twin.compile(nominal)
    progress("simulating the nominal twin on the measured command")
    out0 = twin.simulate(drive, twin.nominal[None, :])
    if not out0.ok[0]:
        raise RuntimeError(f"the nominal model {nominal.source} diverged on {run.source}")
    timings["nominal_s"] = time.perf_counter() - clock
    alignment = align(run.t_s, run["pos_meas_m"], out0.x_m[0], max_shift_s=0.1)
    before = _metrics(run, out0)
    stride = max(1, len(run.t_s) // opts.fit_samples)
    meas = _measured(run, out0, stride)
    effort_name = run.effort_name
    motion = motion_from_position(
        run.t_s,
        run["pos_meas_m"],
        effort_sim=None if out0.effort is None or effort_name is None else out0.effort[0],
        lead_m=twin.lead_m,
        pole_pairs=twin.pole_pairs,
        travel_m=max(float(np.ptp(run["pos_meas_m"])), 1e-6),
        current_q_A=run.signals.get("current_q_A"),
    )
    re0, rp0 = _residuals(run, out0)
    location = locate(
        run.t_s,
        re0 if re0 is not None else rp0,
        run["pos_meas_m"],
        motion.v_m_s,
        residual_name="effort residual" if re0 is not None else "position residual",
        unit=twin.effort_unit if re0 is not None else "m",
        lead_m=twin.lead_m,
        pole_pairs=twin.pole_pairs,
    )
    state = _State(doc=nominal, twin=twin, outputs=out0, cost=cost_of(meas, out0))
    stiffness = None if re0 is not None else _loop_stiffness(twin, drive, out0)
    excluded: list[str] = []
    ranking: list[Candidate] = []
    reports: list[dict] = []
    unfitted: list[dict] = []
    for round_no in range(1, opts.max_effects + 1):
        re, rp = _residuals(run, state.outputs)
        ranking = rank(
            motion,
            effort_residual=re,
            position_residual=rp,
            exclude=tuple(excluded),
            loop_stiffness=stiffness,
            voltage_residual=_voltage_residual(run, state.outputs),
        )
        significant = [c for c in ranking if c.significant]
        if not significant:
            progress(f"round {round_no}: no effect of the library explains a significant part")
            break
        lead = significant[0]
        rivals = [
            c
            for c in significant[: opts.candidates_per_round]
            if c.explained_fraction >= opts.rival_ratio * lead.explained_fraction
        ]
        progress(
            f"round {round_no}: fitting {', '.join(c.name for c in rivals)} "
            "(signature explains "
            + ", ".join(f"{100 * c.explained_fraction:.0f} %" for c in rivals)
            + ")"
        )
        trials = []
        for cand in rivals:
            tried = _try(state, cand, drive, meas, opts)
            if isinstance(tried, str):
                notes.append(tried)
                unfitted.append(
                    {
                        "name": cand.name,
                        "evidence": evidence(cand, _unit(twin, cand)),
                        "reason": tried,
                    }
                )
                excluded.append(cand.name)
                continue
            edit, new_twin, result = tried
            progress(
                f"  {cand.name}: cost {result.cost_initial:.4g} -> {result.cost:.4g} "
                f"({result.evaluations} simulations, "
                + ("converged)" if result.converged else "not converged)")
            )
            if not result.converged:
                notes.append(
                    f"the fit of {cand.name} did not converge ({result.message}); "
                    "kept the last good model"
                )
                excluded.append(cand.name)
                continue
            trials.append((cand, edit, new_twin, result))
        if not trials:
            continue
        # the winner removes the most cost per added degree of freedom relative to what is
        # left (the partial F statistic up to the common effective sample count), so a
        # two-parameter effect must do twice the work of a one-parameter one
        cand, edit, new_twin, result = max(
            trials,
            key=lambda t: (state.cost - t[3].cost) / t[1].added / max(t[3].cost, 1e-300),
        )
        explained = (state.cost - result.cost) / state.cost if state.cost > 0 else 0.0
        if explained < MIN_EXPLAINED:
            notes.append(
                f"{cand.name} was fitted but removed only {100 * explained:.1f} % of the cost "
                f"(less than {100 * MIN_EXPLAINED:.0f} %); not kept"
            )
            excluded.append(cand.name)
            continue
        doc = edit.doc
        for name, value in result.values.items():
            doc = doc.set(name, value)
        params = {k: float(f(_Values(doc))) for k, f in edit.report.items()}
        reports.append(edit.report)
        state.found.append(
            FoundEffect(
                name=cand.name,
                evidence=evidence(cand, _unit(twin, cand)),
                parameters=params,
                explained_fraction=explained,
                component=cand.effect.component,
            )
        )
        if not edit.grid:  # searched whole numbers stay out of the least-squares re-fits
            state.found_free.extend(p for p in edit.own if p not in state.found_free)
        state.doc, state.twin, state.outputs, state.cost = (
            doc,
            new_twin,
            result.outputs,
            result.cost,
        )
        excluded.append(cand.name)
        progress(f"  added {cand.name}: {params}; it removed {100 * explained:.1f} % of the cost")
    if state.found:
        progress("re-fitting the found effects together with the nominal parameters")
        note = _final_joint(state, drive, meas, opts)
        if note is not None:
            notes.append(note)
        state.found = [
            dataclasses.replace(
                e, parameters={k: float(f(_Values(state.doc))) for k, f in r.items()}
            )
            for e, r in zip(state.found, reports, strict=True)
        ]
    timings["identify_s"] = time.perf_counter() - clock
    after = _metrics(run, state.outputs)
    if state.found:
        names = ", ".join(e.name for e in state.found)
        verdict = f"the nominal model misses {names}; with them the gap shrinks as shown"
    elif unfitted:
        names = ", ".join(u["name"] for u in unfitted)
        verdict = f"the residual carries the signature of {names}, which could not be fitted"
    else:
        verdict = "no significant missing effect: the residuals are at the noise level"
    validation = None
    validation_traces = None
    if validate is not None:
        progress(f"validating on {validate.source}")
        vdrive = drive_from_run(validate)
        v0 = twin.simulate(vdrive, twin.nominal[None, :])
        v1 = state.twin.simulate(vdrive, state.twin.nominal[None, :])
        validation = {
            "measured": validate.source,
            "before": _metrics(validate, v0).as_dict(),
            "after": _metrics(validate, v1).as_dict(),
        }
        validation_traces = (
            _trace("nominal", validate, vdrive, v0),
            _trace("augmented", validate, vdrive, v1),
        )
        notes.extend(validate.warnings)
    timings["total_s"] = time.perf_counter() - clock
    diagnosis = Diagnosis(
        measured=run.source,
        config=nominal.source,
        model_path=model_path,
        alignment=alignment,
        before=before,
        after=after,
        before_trace=_trace("nominal", run, drive, out0),
        after_trace=_trace("augmented", run, drive, state.outputs),
        effects=tuple(state.found),
        verdict=verdict,
        location=location,
        ranking=tuple(
            {
                "name": c.name,
                "explained_fraction": c.explained_fraction,
                "p_value": c.p_value,
                "significant": c.significant,
            }
            for c in ranking
        ),
        validation=validation,
        validation_traces=validation_traces,
        named_not_fitted=tuple(unfitted),
        notes=tuple(notes),
        timings_s=timings,
    )
    return diagnosis, state.doc, motion


def write_model(doc: ModelDoc, path: Path, found: tuple[FoundEffect, ...]) -> None:
    header = [f"Augmented model written by feed-twin diagnose from {doc.source}."]
    header += [
        f"Added {e.name} ({e.component}): "
        + ", ".join(f"{k} = {v:.6g}" for k, v in e.parameters.items())
        for e in found
    ]
    doc.dump(path, header)
