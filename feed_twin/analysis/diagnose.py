"""The discrepancy workflow: compare, locate, name, add and fit, and show the gap shrink.

    measured run + nominal model
      -> simulate the nominal twin on the measured command and known disturbances
      -> align (time shift, position offset) and metrics "before"
      -> locate the residual (direction, speed, position, phases, spectrum)
      -> repeat: rank the effect library on the current residual; for the leading significant
         candidates add the effect to the model and fit its own parameters (and those of the
         effects found before) by simulation-based least squares; keep the candidate with
         the best likelihood ratio less a price per added parameter that passes the test
      -> joint selection (analysis.joint): swap found effects for their rivals (ranked on the
         set without them, the others re-fitted) while the set's likelihood less a price per
         parameter gets better; search the searched
         parameters (record delays, a current-offset ripple) again with the others in
      -> re-fit all found effects jointly with the nominal parameters they interact with
      -> metrics "after", optional validation on a second run, report.

Significance: a candidate is fitted only if its signature passed the ranking's statistical test
(partial F-test against the noise left by all signatures, see analysis.ranking); the fitted
effect is kept only if the simulation confirms it by the likelihood-ratio test of
analysis.significance (corrected for the candidates searched, and removing at least
MIN_EXPLAINED of one channel's residual). The channels' weights are estimated again from the
current model before every round (analysis.significance); an effect that lives on part of the
record (a force held at rest) is screened and tested on its support. After each addition the
effects found (the newest too) are re-examined jointly (analysis.reexamine): those whose
parameters collapsed or whose removal costs nothing are dropped. The first samples of a trace
that averages (the window before the twin's start, the twin's settling from a start read off
averaged samples: Twin.first_evidence) are left out of every residual ranked, tested and fitted.
A fit that does not converge within its budget but improved the cost is resumed once from where
it stopped; one that still does not converge is reported and its model discarded: the last good
model stays.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from feed_twin.analysis.appraise import appraise
from feed_twin.analysis.channels import (
    VOLTAGE_Q,
    channel_residuals,
    noise_floors,
    residuals,
    voltage_residual,
    weighted_channels,
)
from feed_twin.analysis.compare import Metrics, align, compute_metrics
from feed_twin.analysis.drive_stage import current_answer, drive_stage, expandable
from feed_twin.analysis.effects import Motion, motion_from_position
from feed_twin.analysis.effort_sign import check_effort_sign
from feed_twin.analysis.fit import SimOutputs, cost_of
from feed_twin.analysis.joint import JointSearch, joint_select
from feed_twin.analysis.locate import Location, locate
from feed_twin.analysis.model_doc import TRACE_WINDOW_SLOT
from feed_twin.analysis.passes import Passes, PassListener, ignore
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.record_scale import at_record_scale
from feed_twin.analysis.report import Diagnosis, FoundEffect, Trace
from feed_twin.analysis.rounds import (
    Context,
    Options,
    Progress,
    State,
    Values,
    drop_collapsed,
    final_joint,
    noop,
    run_round,
)
from feed_twin.analysis.timing import split_timing, timing_line
from feed_twin.analysis.twin import (
    SLOW_COMMAND_S,
    Drive,
    ModelDoc,
    Twin,
    drive_from_run,
    drive_period,
)
from feed_twin.analysis.verdict import Leftover, signature, verdict
from feed_twin.analysis.visibility import (
    Unseen,
    Visibility,
    assess,
    force_constant_correlation,
    position_resolution,
    smooth_staircases,
    too_small,
    with_floor,
)
from feed_twin.io.measured import EFFORT_UNITS, MeasuredRun
from feed_twin.plant.slot_specs import with_unit

__all__ = ["Options", "check_effort_sign", "diagnose", "write_model"]


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


def run_metrics(run: MeasuredRun, out: SimOutputs, row: int = 0) -> Metrics:
    """The twin's metrics on a run; where the run's position zero is not known, it is read
    again at this model (the mean difference), as the fit reads it."""
    name = run.effort_name
    x = run["pos_meas_m"]
    if run.position_offset_free:
        x = x + float(np.mean(out.x_m[row] - x))
    effort_sim = None if out.effort is None or name is None else out.effort[row]
    has_u = voltage_residual(run, out, row) is not None
    return compute_metrics(
        x,
        out.x_m[row],
        None if name is None else run[name],
        effort_sim,
        run[VOLTAGE_Q] if has_u else None,
        out.voltage_q[row] if has_u and out.voltage_q is not None else None,
        effort_unit=None if name is None else EFFORT_UNITS[name],
    )


def _trace(label: str, run: MeasuredRun, drive: Drive, out: SimOutputs) -> Trace:
    name = run.effort_name
    has_u = voltage_residual(run, out) is not None
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


def diagnose(
    run: MeasuredRun,
    nominal: ModelDoc,
    *,
    validate: MeasuredRun | None = None,
    options: Options | None = None,
    progress: Progress = noop,
    passes: PassListener = ignore,
    model_path: str = "model.yaml",
) -> tuple[Diagnosis, ModelDoc, Motion]:
    """Run the workflow on `run`; returns the diagnosis, the final model and the motion used.
    `progress` hears what it says, `passes` each pass as it begins (analysis.passes)."""
    opts = options or Options()
    clock = time.perf_counter()
    timings: dict[str, float] = {}
    notes = list(run.warnings)
    raw = run
    run, smoothed = smooth_staircases(run)
    # a slow record is simulated on the model at its scale (analysis.record_scale): the model
    # the workflow fits and writes from here on
    scaled: list[str] = []
    if opts.record_scale:
        nominal, scaled = at_record_scale(run, nominal, resolution_m=position_resolution(raw))
    counter = Passes(passes, rounds=opts.max_effects, validating=validate is not None, t_s=run.t_s)
    drive, twin, out0 = _simulate_nominal(run, nominal, progress, counter)
    timings["nominal_s"] = time.perf_counter() - clock
    check_effort_sign(run, out0)
    # what the record can show (analysis.visibility): said before fitting, and what it cannot
    # show is not searched
    vis = assess(run, twin, drive.pos_ref_m, out0, raw=raw)
    if vis.blind is not None:
        run = dataclasses.replace(run, effort_blind=vis.blind)
    said = _said([*smoothed, *scaled], run, out0, drive, vis, progress)
    notes.extend([*smoothed, *scaled])
    alignment = align(run.t_s, run["pos_meas_m"], out0.x_m[0], max_shift_s=0.1)
    before = run_metrics(run, out0)
    stride = max(1, len(run.t_s) // opts.fit_samples)
    # the first samples of a trace that averages are not evidence (Twin.first_evidence)
    start = twin.first_evidence(drive)
    floors = with_floor(noise_floors(run, out0, start=start), vis)
    meas = weighted_channels(run, out0, stride, floors, start=start)
    motion = _motion(run, twin, out0, drive)
    re0, rp0 = residuals(run, out0, start=start)
    location = _locate(run, twin, motion, re0, rp0)
    state = State(doc=nominal, twin=twin, outputs=out0, cost=cost_of(meas, out0))
    context = Context(
        run=run,
        drive=drive,
        opts=opts,
        stride=stride,
        floors=floors,
        motion=motion,
        stiffness=None if re0 is not None else _loop_stiffness(twin, drive, out0),
        unit_twin=twin,
        progress=progress,
        notes=notes,
        start=start,
        silent=() if vis.position_evidence else ("position",),
    )
    ranking, unfitted, joint = _identify(state, context, list(vis.unseen_names), counter)
    timings["identify_s"] = time.perf_counter() - clock
    counter.appraisal(state.simulations)
    progress("appraising the final model: intervals, correlations, plausibility, drift")
    appraisal = appraise(state, context, nominal)
    timings["appraise_s"] = appraisal.seconds
    search = {
        "simulations": state.simulations + appraisal.simulations,
        "seconds": time.perf_counter() - clock,
        **(joint.as_dict() if joint is not None else {}),
    }
    after = run_metrics(run, state.outputs)
    named, timing = split_timing((f.effect for f in state.found), twin.base_period_s)
    for t in timing:
        notes.append(timing_line(t, twin.base_period_s))
        progress(notes[-1])
    leftover = _leftover(run, state.outputs, floors, start, motion)
    small = _too_small(vis, state, ranking)
    for u in small:
        said.append(u.line())
        progress(said[-1])
    counter.validation(validate, state.simulations + appraisal.simulations)
    validation, validation_traces = _validate(validate, twin, state.twin, progress, notes)
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
        effects=tuple(named),
        verdict=verdict(
            [e.name for e in named],
            [u["name"] for u in unfitted],
            leftover,
            [str(d["summary"]) for d in appraisal.drifts],
            [u.name for u in vis.unseen if u.by_model],
        ),
        leftover=tuple(c.as_dict() for c in leftover),
        appraisal=appraisal.as_dict(),
        search=search,
        appraisal_lines=tuple(appraisal.lines()),
        location=location,
        ranking=tuple(_ranking_row(c) for c in ranking),
        validation=validation,
        validation_traces=validation_traces,
        named_not_fitted=tuple(unfitted),
        notes=tuple(notes),
        timings_s=timings,
        visibility={
            **vis.as_dict(),
            "said": said,
            "too_small": {u.name: u.reason for u in small},
        },
    )
    return diagnosis, state.doc, motion


def _said(
    said: list[str],
    run: MeasuredRun,
    out0: SimOutputs,
    drive: Drive,
    vis: Visibility,
    progress: Progress,
) -> list[str]:
    """What is said of the record before fitting (`said` so far, what it can show, a force
    constant that friction and weight could hide), each line told to `progress` too."""
    said = [*said, *vis.lines()]
    kt = force_constant_correlation(run, out0, drive.vel_ref_m_s)
    if kt is not None and "torque_constant_error" not in vis.unseen_names:
        said.append(kt)
    for line in said:
        progress(line)
    return said


def _locate(
    run: MeasuredRun,
    twin: Twin,
    motion: Motion,
    re0: np.ndarray | None,
    rp0: np.ndarray | None,
) -> Location:
    """Where the nominal model's residual lives (effort if recorded, else position)."""
    residual = re0 if re0 is not None else rp0
    assert residual is not None, "a record has an effort or a position residual"
    return locate(
        run.t_s,
        residual,
        run["pos_meas_m"],
        motion.v_m_s,
        residual_name="effort residual" if re0 is not None else "position residual",
        unit=twin.effort_unit if re0 is not None else "m",
        lead_m=twin.lead_m,
        pole_pairs=twin.pole_pairs,
    )


def _too_small(vis: Visibility, state: State, ranking: list[Candidate]) -> list[Unseen]:
    """On a slow record, the ranked effects that stayed below its resolution (visibility)."""
    if vis.sample_period_s <= SLOW_COMMAND_S:
        return []
    return list(too_small(vis, [f.name for f in state.found], ranking))


def _simulate_nominal(
    run: MeasuredRun, nominal: ModelDoc, progress: Progress, counter: Passes
) -> tuple[Drive, Twin, SimOutputs]:
    """The measured command as the twin's drive, the compiled nominal twin and its response."""
    drive = drive_from_run(run)
    counter.nominal("compiling the nominal model")
    progress(f"compiling the nominal model {nominal.source}")
    twin = Twin.compile(nominal)
    counter.nominal("simulating the nominal twin")
    progress("simulating the nominal twin on the measured command")
    out0 = twin.simulate(drive, twin.nominal[None, :])
    if not out0.ok[0]:
        raise RuntimeError(f"the nominal model {nominal.source} diverged on {run.source}")
    return drive, twin, out0


def _motion(run: MeasuredRun, twin: Twin, out0: SimOutputs, drive: Drive) -> Motion:
    """The measured motion the effects' signatures are built from (with the command's
    velocity the twin was driven with, and the twin's effort as the trace's other mode
    records it: trace_window's signature)."""
    effort_name = run.effort_name
    other = None
    period, h = drive_period(drive), twin.base_period_s
    if out0.effort is not None and effort_name is not None and round(period / h) > 1:
        now = twin.record_slots(drive)[TRACE_WINDOW_SLOT]
        mode = h if round(now / h) > 1 else period
        other = twin.simulate(drive, twin.nominal[None, :], record=[{TRACE_WINDOW_SLOT: mode}])
        other = other.effort[0] if other.effort is not None and other.ok[0] else None
    motion = motion_from_position(
        run.t_s,
        run["pos_meas_m"],
        effort_sim=None if out0.effort is None or effort_name is None else out0.effort[0],
        lead_m=twin.lead_m,
        pole_pairs=twin.pole_pairs,
        travel_m=max(float(np.ptp(run["pos_meas_m"])), 1e-6),
        current_q_A=_current_q(run, twin),
        v_cmd_m_s=drive.vel_ref_m_s,
        current_answer=_current_answer(run, twin),
        effort_other_mode=other,
    )
    if effort_name is None:
        return motion
    return dataclasses.replace(motion, effort_meas=np.asarray(run[effort_name], dtype=float))


def _current_answer(run: MeasuredRun, twin: Twin):
    """The current loop's answer to a voltage error, for a twin that gives its drive's stage
    but has no Inverter (analysis.drive_stage): the dead time's signature on the effort."""
    stage = drive_stage(twin.doc) if expandable(twin.doc) else None
    return None if stage is None else current_answer(stage, run.t_s)


def _current_q(run: MeasuredRun, twin: Twin) -> np.ndarray | None:
    """The record's q-current [A]: its own, else, for a torque-source twin that gives its
    drive's electrical stage (analysis.drive_stage), the recorded torque over the gain it was
    converted with (the record's current, as the drive measured it)."""
    current = run.signals.get("current_q_A")
    gain = twin.doc.reference_gain
    if current is None and gain and run.effort_name == "torque_cmd_Nm" and expandable(twin.doc):
        return run["torque_cmd_Nm"] / gain
    return current


def _identify(
    state: State, context: Context, excluded: list[str], counter: Passes
) -> tuple[list[Candidate], list[dict], JointSearch | None]:
    """The rounds of ranking, fitting and testing, then the joint re-fit of what they found;
    `state` ends with the augmented model. `excluded`: effects not searched (those the record
    cannot show). Returns the last ranking and the named effects that could not be fitted."""
    opts = context.opts
    ranking: list[Candidate] = []
    unfitted: list[dict] = []
    joint = None
    for round_no in range(1, opts.max_effects + 1):
        counter.round(round_no, state.simulations)
        ranking, more = run_round(round_no, state, context, excluded, unfitted)
        if not more:
            break
    if state.found:
        meas = weighted_channels(
            context.run, state.outputs, context.stride, context.floors, start=context.start
        )
        state.cost = cost_of(meas, state.outputs)
        counter.selection(state.simulations)
        joint = joint_select(state, context, meas)
        counter.joint(state.simulations)
        context.progress("re-fitting the found effects together with the nominal parameters")
        note = final_joint(state, context.drive, meas, opts)
        if note is not None:
            context.notes.append(note)
        drop_collapsed(state, context, "after the joint re-fit")
        state.found = [
            dataclasses.replace(
                f,
                effect=dataclasses.replace(
                    f.effect,
                    parameters={k: float(g(Values(state.doc))) for k, g in f.report.items()},
                ),
            )
            for f in state.found
        ]
    return ranking, unfitted, joint


def _leftover(
    run: MeasuredRun, out: SimOutputs, floors: dict[str, float], start: int, motion: Motion
) -> list[Leftover]:
    """Each channel's residual at the final model against its sample noise, with its signature
    (analysis.verdict): not claimed to be noise."""
    units = {"effort": EFFORT_UNITS.get(run.effort_name or "", ""), "position": "m", "voltage": "V"}
    on = slice(start, None)
    parts = []
    for name, r in channel_residuals(run, out, start=start).items():
        rms = float(np.sqrt(np.mean(r[on] ** 2)))
        words = signature(r[on], run.t_s[on], motion.x_m[on], motion.v_m_s[on], motion.a_m_s2[on])
        parts.append(
            Leftover(
                channel=name,
                unit=units[name],
                rms=rms,
                noise_ratio=rms / floors[name],
                signature=words,
            )
        )
    return parts


def _validate(
    validate: MeasuredRun | None,
    nominal: Twin,
    augmented: Twin,
    progress: Progress,
    notes: list[str],
) -> tuple[dict[str, object] | None, tuple[Trace, Trace] | None]:
    """Metrics and traces of the nominal and the augmented twin on a second run (its staircases
    smoothed and its warnings added to `notes`); None without one."""
    if validate is None:
        return None, None
    validate, smoothed_v = smooth_staircases(validate)
    notes.extend(f"validation: {n}" for n in smoothed_v)
    notes.extend(validate.warnings)
    progress(f"validating on {validate.source}")
    vdrive = drive_from_run(validate)
    v0 = nominal.simulate(vdrive, nominal.nominal[None, :])
    v1 = augmented.simulate(vdrive, augmented.nominal[None, :])
    validation: dict[str, object] = {
        "measured": validate.source,
        "before": run_metrics(validate, v0).as_dict(),
        "after": run_metrics(validate, v1).as_dict(),
    }
    traces = (_trace("nominal", validate, vdrive, v0), _trace("augmented", validate, vdrive, v1))
    return validation, traces


def _ranking_row(c: Candidate) -> dict[str, object]:
    return {
        "name": c.name,
        "explained_fraction": c.explained_fraction,
        "p_value": c.p_value,
        "significant": c.significant,
    }


def write_model(doc: ModelDoc, path: Path, found: tuple[FoundEffect, ...]) -> None:
    header = [f"Augmented model written by feed-twin diagnose from {doc.source}."]
    header += [
        f"Added {e.name} ({e.component}): "
        + ", ".join(with_unit(k, v, 6) for k, v in e.parameters.items())
        for e in found
    ]
    doc.dump(path, header)
