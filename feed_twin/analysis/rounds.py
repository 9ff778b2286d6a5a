"""The rounds of the discrepancy workflow (analysis.diagnose): one round of
rank-fit-test-keep, the re-examination of earlier effects, the final joint re-fit.

The fit's channels and their weights are analysis.channels' (estimated again from the current
model before every round); a candidate is fitted into the model by analysis.trials. See
analysis.diagnose for the workflow as a whole.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from feed_twin.analysis import wording
from feed_twin.analysis.channels import (
    channel_residuals,
    residuals,
    voltage_residual,
    weighted_channels,
)
from feed_twin.analysis.effects import Motion
from feed_twin.analysis.fit import FreeParameter, Measured, SimOutputs, cost_of
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.analysis.plausible import outside_record
from feed_twin.analysis.ranking import Candidate, evidence, rank
from feed_twin.analysis.record_search import AT_EDGE
from feed_twin.analysis.reexamine import (
    Found,
    Without,
    collapsed,
    fell_back,
    neutral_values,
    removable,
    removed,
    split_pairs,
    values_now,
    without,
)
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.significance import ALPHA, compare, effective_samples
from feed_twin.analysis.trials import fit_resumed, try_candidate
from feed_twin.analysis.twin import Drive, Twin
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import MeasuredRun
from feed_twin.plant.effect_api import Edit, interacting
from feed_twin.plant.slot_specs import with_unit

Progress = Callable[[str], None]


@dataclass(frozen=True, kw_only=True)
class Options:
    max_effects: int = 5  # rounds of add-and-fit at most
    candidates_per_round: int = 3  # significant candidates fitted by simulation per round
    rival_ratio: float = 0.5  # fit a rival only if it explains this share of the leader's part
    max_evaluations: int = 30  # least-squares function evaluations per fit
    fit_samples: int = 6000  # cost samples per channel (the record is strided down to this)
    # a slow record is simulated on the model at its scale (analysis.record_scale); False: on
    # the model as written (the cross-check of the two)
    record_scale: bool = True

    def __post_init__(self) -> None:
        for name in ("max_effects", "candidates_per_round", "max_evaluations", "fit_samples"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r}: must be a whole number >= 1")
        if not 0.0 < self.rival_ratio <= 1.0:
            raise ValueError(f"rival_ratio = {self.rival_ratio!r}: must lie in (0, 1]")


@dataclass
class State:
    doc: ModelDoc
    twin: Twin
    outputs: SimOutputs
    cost: float
    found: list[Found] = field(default_factory=list)
    simulations: int = 1  # parameter sets simulated so far (the search's cost), the nominal's too

    def found_free(self) -> list[FreeParameter]:
        return [p for f in self.found for p in f.own]


class Values(dict):
    """Fitted values read from a model document on demand (for the reported parameters)."""

    def __init__(self, doc: ModelDoc) -> None:
        super().__init__()
        self.doc = doc

    def __missing__(self, name: str) -> float:
        return self.doc.get(name)


def unit_of(twin: Twin, cand: Candidate) -> str:
    return {"effort": twin.effort_unit, "voltage": "V"}.get(cand.residual_domain, "m")


def noop(_: str) -> None:
    pass


def joint_free(state: State) -> list[FreeParameter]:
    """The found effects' parameters at their values now, with the nominal parameters they
    interact with (the final joint fit's, and the intervals' and the drift test's)."""
    free = []
    for p in state.found_free():
        if not state.doc.has_slot(p.name):
            continue  # a tie split by a later effect (Coulomb by asymmetric friction)
        free.append(dataclasses.replace(p, initial=state.doc.get(p.name)))
    names = {p.name for p in free}
    gain = state.doc.gain_slot()
    if gain not in names:
        # with a fitted drive gain the mass and friction would be degenerate (the gain scales
        # every force), so they are re-estimated only when the gain is not
        free += [p for p in interacting(state.doc) if p.name not in names]
    return free


def final_joint(state: State, drive: Drive, meas: Measured, opts: Options) -> str | None:
    """Re-fit all found effects together with the nominal parameters they interact with.

    Done once, at the end: re-estimating the mass or the viscous coefficient in every round
    would let them absorb the signature of an effect that is found later. If the joint fit
    does not converge or is not better, the effect-by-effect model stays and the note says so.
    """
    free = joint_free(state)
    twin = Twin.compile(state.doc)
    # resumed once if it ran out of evaluations on the way down, as every fit of a round is:
    # eight parameters (three phase offsets, the mass and four friction terms) take about
    # three Jacobians of the budget, and the effect-by-effect fit it would have improved stayed
    joint = fit_resumed(twin, drive, free, meas, opts.max_evaluations)
    state.simulations += joint.evaluations
    if not joint.converged or joint.cost > state.cost:
        return (
            f"the joint re-fit of the found effects and the nominal parameters did not "
            f"converge or improve ({joint.message}); kept the effect-by-effect fit"
        )
    doc = state.doc
    for name, value in joint.values.items():
        doc = doc.set(name, value)
    try:
        twin = Twin.compile(doc)
    except ConfigError as exc:  # a stiffness run off to infinity: no feed axis
        return (
            f"the joint re-fit of the found effects and the nominal parameters ran to a model "
            f"no feed axis has ({exc}); kept the effect-by-effect fit"
        )
    state.doc, state.twin = doc, twin
    state.outputs, state.cost = joint.outputs, joint.cost
    return None


@dataclass(frozen=True, kw_only=True, eq=False)
class Context:
    """What every round of the workflow works on."""

    run: MeasuredRun
    drive: Drive
    opts: Options
    stride: int
    floors: dict[str, float]  # each channel's sample noise (floors)
    motion: Motion
    stiffness: float | None  # the loop's stiffness for a record without effort
    unit_twin: Twin  # the nominal twin (for the evidence's units)
    progress: Progress
    notes: list[str]
    start: int = 0  # the record's first sample that is evidence (Twin.first_evidence)
    # the candidates fitted and not kept since the model last changed (not ranked again until
    # it changes: they would fit the same way)
    tried: list[str] = field(default_factory=list)
    # channels that carry no evidence in this record (analysis.visibility): not tested
    silent: tuple[str, ...] = ()

    def channels(self, out: SimOutputs) -> dict[str, np.ndarray]:
        found = channel_residuals(self.run, out, start=self.start)
        return {k: v for k, v in found.items() if k not in self.silent}


def run_round(
    round_no: int, state: State, ctx: Context, excluded: list[str], unfitted: list[dict]
) -> tuple[list[Candidate], bool]:
    """One round: rank, fit the leading candidates, keep the best one if the test passes, then
    re-examine the effects found before. Returns the ranking and whether to go on."""
    run, opts, progress = ctx.run, ctx.opts, ctx.progress
    ranking = ranked(ctx, state.outputs, tuple(excluded + ctx.tried))
    significant = [c for c in ranking if c.worth_fitting]
    if not significant:
        progress(f"round {round_no}: no effect of the library explains a significant part")
        return ranking, False
    # the weights of this round: each channel's noise level at the current model
    meas = weighted_channels(run, state.outputs, ctx.stride, ctx.floors, start=ctx.start)
    state.cost = cost_of(meas, state.outputs)
    rivals = choose_rivals(significant, opts)
    progress(
        f"round {round_no}: fitting {', '.join(c.name for c in rivals)} "
        "(signature explains "
        + ", ".join(f"{100 * c.explained_fraction:.0f} %" for c in rivals)
        + ")"
    )
    trials = []
    for cand in rivals:
        tried = try_candidate(
            state.doc, state.found_free(), cand, ctx.drive, meas, opts.max_evaluations
        )
        if isinstance(tried, str):
            _not_fitted(ctx, cand, tried, unfitted)
            excluded.append(cand.name)
            continue
        edit, alone, new_twin, result = tried
        state.simulations += result.evaluations
        progress(
            f"  {cand.name}: cost {result.cost_initial:.4g} -> {result.cost:.4g} "
            f"({result.evaluations} simulations, "
            + ("converged)" if result.converged else "not converged)")
        )
        if not result.converged:
            ctx.notes.append(
                f"the fit of {cand.name} did not converge ({result.message}); "
                "kept the last good model"
            )
            excluded.append(cand.name)
            continue
        trials.append((cand, edit, alone, new_twin, result))
    if not trials:
        return ranking, True
    judged = _judged(state, ctx, trials)
    for verdict, cand, edit, alone, new_twin, result in judged:
        if verdict.significant:
            adopt(
                state, ctx, cand, edit=edit, alone=alone, new_twin=new_twin, result=result,
                explained_by=verdict.explained,
            )  # fmt: skip
            excluded.append(cand.name)
            # the model changed: the rivals tried so far are ranked again on its residual (a
            # backlash tried beside the Coulomb force that hid it is found once that is in)
            ctx.tried.clear()
            reexamine_found(state, ctx, meas)
            return ranking, True
        ctx.notes.append(
            f"{cand.name} was fitted but is not significant: it {verdict.words()}; not kept"
        )
    # the model did not change: the rivals would fit the same way next round
    return ranking, True


def ranked(ctx: Context, outputs: SimOutputs, exclude: tuple[str, ...]) -> list[Candidate]:
    """The library ranked on the residuals of `outputs` (analysis.ranking), its force-like
    weights as forces at the table."""
    re, rp = residuals(ctx.run, outputs, start=ctx.start)
    ranking = rank(
        ctx.motion,
        effort_residual=re,
        position_residual=rp,
        exclude=exclude,
        loop_stiffness=ctx.stiffness,
        voltage_residual=voltage_residual(ctx.run, outputs, start=ctx.start),
    )
    # the edits take force-like weights as forces at the table, converted as for a friction
    # (they are starting values of the fit); without a screw they stay in the effort's unit
    per_effort = ctx.unit_twin.doc.force_per_effort(ctx.unit_twin.effort_unit) or 1.0
    return [
        dataclasses.replace(c, force_per_unit=per_effort) if c.residual_domain == "effort" else c
        for c in ranking
    ]


def choose_rivals(ranked: list[Candidate], opts: Options) -> list[Candidate]:
    """The candidates of one round fitted by simulation: the leading ones (at most
    candidates_per_round, each explaining rival_ratio of the leader's share), and the leader of
    every other residual, and beside a residual's rival ranked there on its fallback residual
    the best of the effects ranked there on their own. Shares of different residuals do not
    compare: a feedback delay in the loop (27 % of the effort residual) lost its place to three
    timings of the record that each took 98 % of the position's, and the one of them kept took
    the loop's delay too."""
    lead = ranked[0]
    rivals = [
        c
        for c in ranked[: opts.candidates_per_round]
        if c.explained_fraction >= opts.rival_ratio * lead.explained_fraction
    ]
    for c in ranked:
        if all(r.residual_domain != c.residual_domain for r in rivals):
            rivals.append(c)  # the first of its residual's: the ranking's order
    for r in list(rivals):
        if r.residual_domain == r.effect.domain:
            continue
        # a residual's rival ranked there on its fallback (a dead time without voltages, on
        # the effort) takes no place from the best of that residual's own effects: a 4 ms
        # feedback delay (measurement_delay) lost its effort slot to the dead time's current
        # dip (53 % of the effort residual) and was named as a command delay
        own = next(
            (c for c in ranked if c.residual_domain == c.effect.domain == r.residual_domain), None
        )
        if own is not None and own not in rivals:
            rivals.append(own)
    return rivals


def _judged(state: State, ctx: Context, trials: list) -> list:
    """The trials that are findings, each with its test against the model now, best first."""
    # each trial's test against the model now; the best by an information criterion on the
    # likelihood ratio (module docstring) that passes the test is kept (a drive gain that bends
    # the position at the effort's expense must not hide the holding force fitted beside it)
    judged, befores = [], []
    for cand, edit, alone, new_twin, result in trials:
        ctx.tried.append(cand.name)
        meaningless = no_finding(state, ctx, cand, edit, alone, result)
        if meaningless is not None:
            ctx.notes.append(f"{meaningless}; not kept")
            continue
        before = ctx.channels(_baseline(state, ctx, edit, alone, new_twin))
        verdict = compare(
            before,
            ctx.channels(result.outputs),
            added=edit.added,
            searched=_searched(cand, edit, len(trials)),
            own=cand.residual_domain,
            support=cand.support,
        )
        judged.append((verdict, cand, edit, alone, new_twin, result))
        befores.append(before)
    afters = [ctx.channels(j[-1].outputs) for j in judged]
    yardstick = (
        effective_counts(afters[int(np.argmin([j[-1].cost for j in judged]))]) if judged else {}
    )
    scores = [
        information(before, after, yardstick, j[2].added)
        for j, before, after in zip(judged, befores, afters, strict=True)
    ]
    order = sorted(range(len(judged)), key=lambda k: scores[k], reverse=True)
    return [judged[k] for k in order]


def _baseline(state: State, ctx: Context, edit: Edit, alone, new_twin: Twin) -> SimOutputs:
    """What a trial is tested against: the model now, or, for an edit that writes a new stage
    (Edit.restructures: a drive's electrical stage for its dead time), the edited model with
    the effect's own parameters at their neutral values, so that what the new stage does at
    any size (the current loop's lag) is not counted for the effect."""
    if not edit.restructures:
        return state.outputs
    slots = tuple(p.name for p in alone)
    row = new_twin.nominal.copy()
    for slot, value in neutral_values(state.doc, model_of(edit.doc), slots).items():
        for i in new_twin.index[slot]:
            row[i] = value
    return new_twin.simulate(ctx.drive, row[None, :])


def no_finding(
    state: State, ctx: Context, cand: Candidate, edit: Edit, alone, result
) -> str | None:
    """Why a converged fit of a candidate is no finding (its parameters fell back to the values
    without it, they lie outside what the record holds, or the model is no feed axis's), None
    if it is one."""
    if _collapsed_in_fit(state, edit, alone, result):
        return (
            f"{cand.name} was fitted but its parameters fell back to the values without it "
            f"({', '.join(f'{k} = {v:.4g}' for k, v in result.values.items())})"
        )
    meaningless = outside_record(cand.name, _fitted(edit, result), ctx.motion)
    return meaningless if meaningless is not None else _no_feed_axis(cand.name, edit, result)


# the price of one added parameter in the likelihood ratio: the test's own threshold for one
# parameter (chi^2(1) at ALPHA), so a second parameter must earn what a first one must
PARAMETER_PRICE = float(stats.chi2.isf(ALPHA, 1))


def effective_counts(channels: dict[str, np.ndarray]) -> dict[str, float]:
    """Each channel's effective sample count (analysis.significance.effective_samples)."""
    return {name: effective_samples(r) for name, r in channels.items()}


def information(
    before: dict[str, np.ndarray],
    after: dict[str, np.ndarray],
    counts: dict[str, float],
    added: int,
) -> float:
    """The likelihood ratio of `after` against `before`, with every rival's channels counted
    alike (`counts`: the effective samples of the best-fitting rival's residuals), less
    PARAMETER_PRICE per added parameter: what ranks the rivals of one round. Dividing the gain
    by the parameter count, as before, made a two-parameter effect that fits much better
    (asymmetric friction, cost 2389) lose to a one-parameter one that takes its mean (a
    constant force, cost 3515); each rival's own effective count, as the test uses, would let
    its few per cent decide between two rivals that fit alike (a Coulomb force and a Stribeck
    law at a speed above the record's)."""
    lr = 0.0
    for name, a in after.items():
        rss_before, rss_after = float(np.dot(before[name], before[name])), float(np.dot(a, a))
        if rss_before > 0.0:
            lr += counts[name] * math.log(rss_before / max(rss_after, 1e-300))
    return lr - PARAMETER_PRICE * added


def _fitted_doc(edit: Edit, result) -> ModelDoc:
    doc = model_of(edit.doc)
    for name, value in result.values.items():
        doc = doc.set(name, value)
    return doc


def _fitted(edit: Edit, result) -> dict[str, float]:
    """The effect's reported parameters at the fit's result."""
    doc = _fitted_doc(edit, result)
    return {k: float(f(Values(doc))) for k, f in edit.report.items()}


def _no_feed_axis(name: str, edit: Edit, result) -> str | None:
    """Why the fitted model is no feed axis (the plant's plausibility ranges reject it: a
    bearing stiffness that ran off to 1e29 N/m), None if it is one."""
    try:
        Twin.compile(_fitted_doc(edit, result))
    except ConfigError as exc:
        return f"{name} was fitted to a model no feed axis has ({exc})"
    return None


def _not_fitted(ctx: Context, cand: Candidate, why: str, unfitted: list[dict]) -> None:
    """A candidate the model cannot carry: said, and kept as named but not fitted."""
    ctx.notes.append(why)
    evidence_ = evidence(cand, unit_of(ctx.unit_twin, cand))
    unfitted.append({"name": cand.name, "evidence": evidence_, "reason": why})


def _collapsed_in_fit(state: State, edit: Edit, alone: list[FreeParameter], result) -> bool:
    """The fit took the new effect's size parameters back to within COLLAPSE of the values
    without it, from where the ranking's weights started them: what the fit gained came from
    fitting the effects found before again, not from this one."""
    if edit.grid:
        return False
    slots = tuple(p.name for p in alone)
    neutral = neutral_values(state.doc, model_of(edit.doc), slots)
    start = {p.name: p.initial for p in alone}
    return fell_back(neutral, start, {s: result.values.get(s, start[s]) for s in slots})


def _searched(cand: Candidate, edit: Edit, rivals: int) -> int:
    """The alternatives a kept effect was chosen from: its signature's variants and the rivals
    fitted beside it. A grid over the effect's own size that holds the model's current value (a
    delay from 0 up) is a fit of one parameter nested in the model without it, whose likelihood
    ratio is chi^2(1) (Wilks): no search of unrelated alternatives. Any other grid is one."""
    nested = bool(edit.grid) and edit.own[0].initial in edit.grid
    return max(cand.searched, 1 if nested else len(edit.grid), 1) * rivals


def adopt(state, ctx, cand, *, edit, alone, new_twin, result, explained_by) -> None:
    """Adopt the fitted effect into the state."""
    before = state.doc
    doc = model_of(edit.doc)
    for name, value in result.values.items():
        doc = doc.set(name, value)
    explained = (state.cost - result.cost) / state.cost if state.cost > 0 else 0.0
    params = {k: float(f(Values(doc))) for k, f in edit.report.items()}
    slots = tuple(p.name for p in alone)
    pairs, members = split_pairs(before, doc, slots)
    state.found.append(
        Found(
            effect=FoundEffect(
                name=cand.name,
                evidence=evidence(cand, unit_of(ctx.unit_twin, cand)),
                parameters=params,
                explained_fraction=explained,
                component=cand.effect.component,
            ),
            # searched whole numbers stay out of the least-squares re-fits
            own=() if edit.grid else tuple(alone),
            neutral=neutral_values(before, doc, slots),
            at_discovery={s: doc.get(s) for s in slots},
            report=edit.report,
            added=edit.added,
            pairs=pairs,
            members=members,
        )
    )
    state.doc, state.twin, state.outputs, state.cost = doc, new_twin, result.outputs, result.cost
    values = ", ".join(with_unit(k, v) for k, v in params.items())
    ctx.progress(f"  added {cand.name}: {values}; it {wording.shares(explained_by)}")
    if result.message.endswith(AT_EDGE):  # a record slot's search said so
        ctx.notes.append(f"{cand.name}: {result.message}")


def drop_collapsed(state: State, ctx: Context, when: str) -> None:
    """Remove the effects whose fitted parameters fell back to their neutral values, until
    none is left (removing one can leave another at its own: an asymmetry of a Coulomb force
    that was itself removed)."""
    while (f := next((f for f in state.found if collapsed(f, state.doc)), None)) is not None:
        before = values_now(f, state.doc)
        state.doc = removed(f, state.doc)
        state.found.remove(f)
        ctx.notes.append(
            f"{f.name} was dropped {when}: its fitted parameters collapsed to the values "
            f"without it ({before})"
        )
    state.twin = Twin.compile(state.doc)
    state.outputs = state.twin.simulate(ctx.drive, state.twin.nominal[None, :])
    state.simulations += 1


def refitted_without(state: State, ctx: Context, meas: Measured, target: Found) -> Without | None:
    """The set without `target`, the other effects found fitted again (reexamine.without); its
    simulations count in `state`."""
    others = [f for f in state.found if f is not target]
    gone = without(
        target,
        others,
        state.doc,
        state.outputs,
        drive=ctx.drive,
        meas=meas,
        channels=ctx.channels,
        max_evaluations=ctx.opts.max_evaluations,
    )
    state.simulations += 1 if gone is None else gone.simulations
    return gone


def reexamine_found(state: State, ctx: Context, meas: Measured) -> None:
    """Examine the effects found jointly (analysis.reexamine), the newest one too: its fit
    re-fitted the effects found before, and what that alone gains is no evidence for it."""
    if len(state.found) < 2:
        return
    newest = state.found[-1]
    if any(collapsed(f, state.doc) for f in state.found[:-1]):
        drop_collapsed(state, ctx, "once a later effect was in the model")
    for target in list(state.found):
        if not removable([target], state.doc):
            continue
        gone = refitted_without(state, ctx, meas, target)
        if gone is None or gone.verdict.significant:
            continue
        state.found.remove(target)
        state.doc, state.twin, state.outputs = gone.doc, gone.twin, gone.outputs
        when = (
            "with the effects found before fitted again"
            if target is newest
            else "once a later effect was in the model"
        )
        ctx.notes.append(
            f"{target.name} was dropped {when}: removing it costs nothing significant "
            f"(with it the model {gone.verdict.words()})"
        )
        ctx.progress(f"  dropped {target.name}: removing it costs nothing significant")
