"""The discrepancy workflow: compare, locate, name, add and fit, and show the gap shrink.

    measured run + nominal model
      -> simulate the nominal twin on the measured command and known disturbances
      -> align (time shift, position offset) and metrics "before"
      -> locate the residual (direction, speed, position, phases, spectrum)
      -> repeat: rank the effect library on the current residual; for the leading significant
         candidates add the effect to the model and fit it (with the nominal parameters it
         interacts with) by simulation-based least squares; keep the candidate whose fit
         removes the most cost, if that reduction is itself significant
      -> metrics "after", optional validation on a second run, report.

Significance of a fitted effect: the cost reduction is tested like the ranking (partial F-test
with the effective sample count of the new residual) and must exceed MIN_EXPLAINED of the cost.
A fit that does not converge is reported and its model discarded; the last good model stays.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import stats

from feed_twin.analysis.compare import Metrics, align, compute_metrics
from feed_twin.analysis.edits import EDITS, Edit
from feed_twin.analysis.effects import (
    ALPHA,
    MIN_EXPLAINED,
    Candidate,
    Motion,
    evidence,
    motion_from_position,
    rank,
)
from feed_twin.analysis.fit import FitResult, Measured, SimOutputs, cost_of, fit
from feed_twin.analysis.locate import locate
from feed_twin.analysis.report import Diagnosis, FoundEffect, Trace
from feed_twin.analysis.twin import Drive, ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import MeasuredRun

Progress = Callable[[str], None]


@dataclass(frozen=True, kw_only=True)
class Options:
    max_effects: int = 5  # rounds of add-and-fit at most
    candidates_per_round: int = 3  # significant candidates fitted by simulation per round
    rival_ratio: float = 0.5  # fit a rival only if it explains this share of the leader's part
    max_evaluations: int = 30  # least-squares function evaluations per fit
    fit_samples: int = 6000  # cost samples per channel (the record is strided down to this)


@dataclass
class _State:
    doc: ModelDoc
    twin: Twin
    outputs: SimOutputs
    cost: float
    found: list[FoundEffect] = field(default_factory=list)


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


def _measured(run: MeasuredRun, out: SimOutputs, stride: int) -> Measured:
    re, rp = _residuals(run, out)
    name = run.effort_name
    return Measured(
        x_m=run["pos_meas_m"],
        effort=None if name is None or out.effort is None else run[name],
        scale_x=max(float(np.sqrt(np.mean(rp**2))), 1e-9),
        scale_effort=1.0 if re is None else max(float(np.sqrt(np.mean(re**2))), 1e-9),
        stride=stride,
    )


def _metrics(run: MeasuredRun, out: SimOutputs, row: int = 0) -> Metrics:
    name = run.effort_name
    effort_sim = None if out.effort is None or name is None else out.effort[row]
    return compute_metrics(
        run["pos_meas_m"], out.x_m[row], None if name is None else run[name], effort_sim
    )


def _trace(label: str, run: MeasuredRun, drive: Drive, out: SimOutputs) -> Trace:
    name = run.effort_name
    return Trace(
        label=label,
        t_s=run.t_s,
        pos_cmd_m=drive.pos_ref_m,
        x_meas_m=run["pos_meas_m"],
        x_sim_m=out.x_m[0],
        effort_meas=None if name is None else run[name],
        effort_sim=None if out.effort is None or name is None else out.effort[0],
        effort_name=name,
    )


def _reduction_significant(meas: Measured, out: SimOutputs, before: float, after: float, p: int):
    """Partial F-test of a cost reduction, effective samples from the new residual."""
    from feed_twin.analysis.fit import residual_vector

    e = None if out.effort is None else out.effort[0]
    r = residual_vector(meas, out.x_m[0], e)
    half = len(r) // (2 if meas.effort is not None and e is not None else 1)
    n_eff = 0.0
    for part in (r[:half], r[half:]) if half < len(r) else (r,):
        part = part - part.mean()
        denom = float(np.dot(part, part))
        rho = float(np.dot(part[1:], part[:-1]) / denom) if denom > 0 else 0.0
        rho = min(max(rho, 0.0), 0.9999)
        n_eff += len(part) * (1.0 - rho) / (1.0 + rho)
    n_eff = max(n_eff, p + 2.0)
    if after <= 0.0:
        return True, 0.0
    f_stat = ((before - after) / p) / (after / (n_eff - p))
    p_value = float(stats.f.sf(f_stat, p, n_eff - p)) if f_stat > 0 else 1.0
    explained = (before - after) / before if before > 0 else 0.0
    return (p_value < ALPHA and explained >= MIN_EXPLAINED), p_value


def _try(
    state: _State, cand: Candidate, drive: Drive, meas: Measured, opts: Options
) -> tuple[Edit, Twin, FitResult] | str:
    try:
        edit = EDITS[cand.name](state.doc, cand)
    except (KeyError, LookupError) as exc:
        return f"{cand.name}: cannot be added to this model ({exc})"
    twin = Twin.compile(edit.doc)
    result = fit(
        lambda params: twin.simulate(drive, params),
        twin.nominal,
        twin.index,
        edit.free,
        meas,
        max_evaluations=opts.max_evaluations,
    )
    return edit, twin, result


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
    excluded: list[str] = []
    ranking: list[Candidate] = []
    for round_no in range(1, opts.max_effects + 1):
        re, rp = _residuals(run, state.outputs)
        ranking = rank(motion, effort_residual=re, position_residual=rp, exclude=tuple(excluded))
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
        ok, p_value = _reduction_significant(
            meas, result.outputs, state.cost, result.cost, edit.added
        )
        explained = (state.cost - result.cost) / state.cost if state.cost > 0 else 0.0
        if not ok:
            notes.append(
                f"{cand.name} was fitted but removed only {100 * explained:.1f} % of the cost "
                f"(p = {p_value:.2g}); not kept"
            )
            excluded.append(cand.name)
            continue
        doc = edit.doc
        for name, value in result.values.items():
            doc = doc.set(name, value)
        params = {k: float(f(result.values)) for k, f in edit.report.items()}
        state.found.append(
            FoundEffect(
                name=cand.name,
                evidence=evidence(
                    cand, twin.effort_unit if cand.effect.domain == "effort" else "m"
                ),
                parameters=params,
                explained_fraction=explained,
                component=cand.effect.component,
            )
        )
        state.doc, state.twin, state.outputs, state.cost = (
            doc,
            new_twin,
            result.outputs,
            result.cost,
        )
        excluded.append(cand.name)
        progress(f"  added {cand.name}: {params}; it removed {100 * explained:.1f} % of the cost")
    timings["identify_s"] = time.perf_counter() - clock
    after = _metrics(run, state.outputs)
    if state.found:
        names = ", ".join(e.name for e in state.found)
        verdict = f"the nominal model misses {names}; with them the gap shrinks as shown"
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
