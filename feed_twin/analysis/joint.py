"""Joint selection: the effects the rounds found one at a time, re-examined as a set.

The rounds (analysis.rounds) are a forward selection: each adds the best of its rivals on the
residual of the model so far, and re-examines the effects found before by removing each one.
Neither step can replace an effect chosen early by one that only a later effect shows to be
right. On a machine with a heavier slide, a weight and more Coulomb friction, a drive gain 27 %
low scales every force at once and took the second round ahead of the mass (the forces found
later were then fitted 27 % small, and a viscous term absorbed the rest): a set with one
parameter more that fits no better than the true one.

So once the rounds end, each found effect is swapped for each of its rivals: the effects of the
library (none found) that the residual of the set without it ranks as worth fitting, in the
same residual, explaining at least rival_ratio of what the effect's own signature explains
there (a round's rule for its rivals). That residual is the set's without it with the others
fitted again (reexamine.without, as the rounds' removal test fits them): the forces found in
the scale of a drive gain, left as they were, leave a residual that only the gain explains. A
rival is fitted into the model without the found effect together with the others' own
parameters, exactly as a round fits a candidate (analysis.trials), and must be a finding there
(rounds.no_finding). The set with it is scored against the set now by the likelihood of both
channels, position and effort together, each weighed by its effective samples (the concentrated
likelihood sum_c n_c ln RSS_c, rounds.information) less PARAMETER_PRICE per parameter: an
effect that removes most of one channel's residual is not hidden by a few per cent of another,
nor by its parameter count. A set that could win only by losing some of its other effects'
parameters (the viscous term the drive gain needed) is pruned first, as the rounds prune
(rounds.reexamine_found: collapsed effects and those whose removal costs nothing are dropped),
and scored as pruned. The best swap that scores better than the set now by SWAP_MARGIN is
kept, and the search repeats on the new set, MAX_SWAPS times at most. Last, the found effects'
searched parameters are searched again with the others in (`searched_again`).

A found effect can stand for two. Where no swap wins, each found effect's best-scoring swap is
extended as one more round would extend it (`_extended`: the library ranked on the swapped
set's residual, its rivals fitted in with the set's parameters, the best-scoring one the test
keeps there), then pruned and scored as above; an extended set must keep no more parameters
than the set now (an exchange: whether the model needs one more effect is the rounds' test; a
synthetic EMPS record's heavier table, named alone, scored 1310 better as a drive gain beside a
viscous term). On the truth machine's heavier slide (seed 2) with the drive's current loop in
the twin, the rounds take the drive gain first at 1.347 (the slide's inertia ratio is 1.316;
the twin without the loop took 1.369, its missing back-EMF lag acting as extra inertia), then
the weight; what is left is the friction the gain scaled wrong (Coulomb 60 x 1.347 for 117 N,
viscous 300 x 1.347 for 300 N s/m), not an acceleration: a viscous term explains 33 %, the mass
15 %, and the rounds take the viscous term. The mass alone in the gain's place then leaves the
Coulomb force out (score -349); with the Coulomb force fitted in beside it (a Stribeck law led
that residual's ranking, 58 % against 37 %, and fitted worse) and the viscous term pruned, the
set scores 109 better: mass 321.5 kg for 322.1, weight -131.1 N for -131.3, Coulomb 116.6 N for
116.9.

The rivals were once the rounds' runners-up only (rivals fitted in some round and not kept),
ranked on the set without the effect as it stood: on the truth machine's heavier slide (seed 2,
at the drive's loop rates, before the twin had the drive's current loop) the rounds took the
drive gain 27 % low first, then the weight and the mass; the Coulomb force was never a round's
rival, and without the gain, the forces still in its scale, it explained 11 % of the residual
against the gain's 84 %. With the others fitted again it was the gain's rival, and the set
{Coulomb, weight, mass} scored 119 better.

Cost: one re-fit of the others per found effect, one least-squares fit per pair tried (its
Jacobians are batches of the engine, analysis.fit), where none wins the fits of each best
swap's residual's rivals (candidates_per_round at most), the removal tests of the sets worth
pruning, and the searches again (one simulation and shifts of its output each); counted in the
search's simulations (Diagnosis.search: joint_trials, joint_simulations, joint_seconds) and
said in the report.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

from feed_twin.analysis.fit import FreeParameter, Measured, cost_of
from feed_twin.analysis.model_doc import model_of
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.reexamine import Found, removable, removed
from feed_twin.analysis.rounds import (
    PARAMETER_PRICE,
    Context,
    State,
    adopt,
    choose_rivals,
    effective_counts,
    information,
    no_finding,
    noop,
    ranked,
    reexamine_found,
    refitted_without,
)
from feed_twin.analysis.significance import compare
from feed_twin.analysis.trials import grid_search, try_candidate
from feed_twin.analysis.twin import Twin

MAX_SWAPS = 2  # swaps kept at most (each one followed by a new search over the new set)
# how much better (in the likelihood's units, rounds.information) a swapped set must score than
# the set the rounds chose: half a parameter's price, so that a rival that fits alike with as
# many parameters (an alias) does not flip the rounds' choice on the float noise of its fit
SWAP_MARGIN = 0.5 * PARAMETER_PRICE


@dataclass(frozen=True, kw_only=True, eq=False)
class Swap:
    """A set with one found effect replaced by a rival, fitted and pruned."""

    out: str  # the found effect taken out
    into: str  # the rival put in
    state: State  # the set, fitted
    score: float  # its information against the set now (positive: better)
    dropped: tuple[str, ...]  # the effects the pruning removed besides `out`
    extra: str | None = None  # the effect fitted in beside `into` (analysis.joint._extended)


@dataclass(frozen=True, kw_only=True)
class JointSearch:
    """What the joint selection did, for the report."""

    trials: int  # sets fitted
    simulations: int  # parameter sets simulated
    seconds: float
    swaps: tuple[str, ...]  # the swaps kept and the searched values moved, in words

    def as_dict(self) -> dict[str, float]:
        """The search's cost, as Diagnosis.search holds it (the swaps are in the notes)."""
        return {
            "joint_trials": float(self.trials),
            "joint_simulations": float(self.simulations),
            "joint_seconds": self.seconds,
        }


def parameters(found: list[Found]) -> int:
    """The degrees of freedom a set of effects adds to the nominal model."""
    return sum(f.added for f in found)


def score(ctx: Context, now: State, trial: State) -> float:
    """The trial set's information against the set now (rounds.information), both channels'
    effective samples counted at the better-fitting of the two."""
    before, after = ctx.channels(now.outputs), ctx.channels(trial.outputs)
    counts = effective_counts(after if trial.cost < now.cost else before)
    added = parameters(trial.found) - parameters(now.found)
    return information(before, after, counts, added)


def joint_select(state: State, ctx: Context, meas: Measured) -> JointSearch:
    """Swap found effects for their rivals while a swap scores better, then search the searched
    parameters again (module docstring); `state` ends with the chosen set. Returns the
    search's cost and what it changed."""
    clock, start_sims = time.perf_counter(), state.simulations
    trials, kept = 0, []
    # an effect a kept swap took out is not swapped back in: the sets are fitted from where the
    # search stands, and each swap's score against its own set is no order over all of them
    # (the truth machine's drive gain at seed 102 went in for a Coulomb force at +17, and the
    # Coulomb force back in for it at +46, a re-fit of the same set that had scored below)
    out: set[str] = set()
    for _ in range(MAX_SWAPS):
        pairs = [
            (f, c)
            for f in state.found
            if removable([f], state.doc)
            for c in _rivals(state, ctx, meas, f)
            if c.name not in out
        ]
        if not pairs:
            break
        ctx.progress(
            f"joint selection: {len(pairs)} swaps of the {len(state.found)} found effects for "
            f"their rivals ({', '.join(f'{c.name} for {f.name}' for f, c in pairs)})"
        )
        best: Swap | None = None
        # each target's best-scoring swap that does not win, fitted (`_extended` extends it)
        losers: dict[str, Fitted] = {}
        for target, cand in pairs:
            trials += 1
            fitted = _fitted_swap(state, ctx, meas, target, cand)
            if fitted is None:
                continue
            swap = _pruned(state, ctx, meas, fitted.copy(), None)
            if swap is not None and swap.score > SWAP_MARGIN:
                best = _better(best, swap)
            elif fitted.exchange and (
                target.name not in losers or fitted.gain > losers[target.name].gain
            ):
                losers[target.name] = fitted
        if best is None:
            trials += len(losers)
            best = _best_extended(state, ctx, meas, list(losers.values()))
        if best is None:
            break
        out.add(best.out)
        kept.append(_keep(state, ctx, best))
    kept += searched_again(state, ctx, meas)
    return JointSearch(
        trials=trials,
        simulations=state.simulations - start_sims,
        seconds=time.perf_counter() - clock,
        swaps=tuple(kept),
    )


def _rivals(state: State, ctx: Context, meas: Measured, target: Found) -> list[Candidate]:
    """The effects worth swapping in for `target`: ranked on the residual of the set without
    it, the others fitted again (reexamine.without), they are worth fitting there and explain
    at least rival_ratio of what the target's own signature explains, as a round's rivals must
    (rounds.choose_rivals). The candidates carry that ranking's weights (the fit's starting
    values)."""
    gone = refitted_without(state, ctx, meas, target)
    if gone is None:
        return []
    found = {f.name for f in state.found}
    ranking = ranked(ctx, gone.outputs, tuple(found - {target.name}))
    own = next((c.explained_fraction for c in ranking if c.name == target.name), 0.0)
    domain = next((c.residual_domain for c in ranking if c.name == target.name), None)
    return [
        c
        for c in ranking
        if c.name not in found
        and c.worth_fitting
        and c.residual_domain == domain
        and c.explained_fraction >= ctx.opts.rival_ratio * own
    ]


def _keep(state: State, ctx: Context, swap: Swap) -> str:
    """Adopt the swapped (and pruned) set into `state`; the swap in words."""
    new = swap.state
    state.doc, state.twin, state.outputs, state.cost = new.doc, new.twin, new.outputs, new.cost
    state.found = new.found
    also = f" with {swap.extra}" if swap.extra else ""
    also += f", without {', '.join(swap.dropped)}" if swap.dropped else ""
    words = (
        f"joint selection: {swap.into} in place of {swap.out}{also}; the set scores "
        f"{swap.score:.3g} better (the likelihood of all channels less {PARAMETER_PRICE:.3g} "
        "per parameter)"
    )
    ctx.notes.append(words)
    ctx.progress(f"  {words}")
    return words


@dataclass(frozen=True, kw_only=True, eq=False)
class Fitted:
    """A swap fitted, before its pruning: `trial` is the set with `target` replaced by
    `cand`, `gain` its score against the set now."""

    target: Found
    cand: Candidate
    trial: State
    gain: float
    # an extension of it could be an exchange (`_pruned`): one more effect (a parameter at
    # least) with all the others pruned keeps no more parameters than the set now
    exchange: bool

    def copy(self) -> Fitted:
        """The same swap with a set of its own (the pruning removes effects from it)."""
        trial = dataclasses.replace(self.trial, found=list(self.trial.found))
        return dataclasses.replace(self, trial=trial)


def _fitted_swap(
    state: State, ctx: Context, meas: Measured, target: Found, cand: Candidate
) -> Fitted | None:
    """The set with `target` replaced by `cand`, fitted; None if the rival is no finding
    there. The simulations count in `state`."""
    others = [f for f in state.found if f is not target]
    doc = removed(target, state.doc)
    free = [
        dataclasses.replace(p, initial=doc.get(p.name))
        for f in others
        for p in f.own
        if doc.has_slot(p.name)
    ]
    base = State(
        doc=doc, twin=state.twin, outputs=state.outputs, cost=state.cost, found=list(others)
    )
    trial = _fitted_in(base, _quiet(ctx), meas, cand, free, state)
    if trial is None:
        return None
    # in the target's place: the report lists the effects in the order the search took them
    trial.found.insert(state.found.index(target), trial.found.pop())
    exchange = parameters(trial.found) + 1 - parameters(others) <= parameters(state.found)
    return Fitted(
        target=target, cand=cand, trial=trial, gain=score(ctx, state, trial), exchange=exchange
    )


def _quiet(ctx: Context) -> Context:
    """The context of a trial set: its notes and progress go nowhere."""
    return dataclasses.replace(ctx, notes=[], progress=noop, tried=[])


def _best_extended(state: State, ctx: Context, meas: Measured, losers: list[Fitted]) -> Swap | None:
    """The best of the swaps `losers` extended (`_extended`) and pruned that scores better
    than the set now by SWAP_MARGIN, None if none does."""
    best: Swap | None = None
    for fitted in losers:
        extended = _extended(state, ctx, meas, fitted.trial, fitted.target)
        if extended is None:
            continue
        more = dataclasses.replace(fitted, trial=extended, gain=score(ctx, state, extended))
        swap = _pruned(state, ctx, meas, more, extended.found[-1].name)
        if swap is not None and swap.score > SWAP_MARGIN:
            best = _better(best, swap)
    return best


def _better(best: Swap | None, swap: Swap) -> Swap:
    return swap if best is None or swap.score > best.score else best


def _pruned(
    state: State, ctx: Context, meas: Measured, fitted: Fitted, extra: str | None
) -> Swap | None:
    """The swap `fitted` (extended by the effect `extra`, if given) pruned where that could
    make it win; None if the pruning takes the rival out (or `extra`), or leaves an extended
    set more parameters than the set now. The simulations count in `state`."""
    trial, cand, gain = fitted.trial, fitted.cand, fitted.gain
    # pruned when it could win (pruning can at most take back the price of the other effects'
    # parameters), a winner too: a rival that splits a tie (asymmetric friction in place of
    # a viscous one) is itself removed by tying the pair at its mean, which keeps the effect it
    # replaced in the model with no name
    kept = [f for f in trial.found if f.name not in (cand.name, extra)]
    if gain + PARAMETER_PRICE * parameters(kept) > SWAP_MARGIN:
        names = {f.name for f in trial.found}
        reexamine_found(trial, _quiet(ctx), meas)
        trial.cost = cost_of(meas, trial.outputs)
        dropped = tuple(sorted(names - {f.name for f in trial.found}))
        # the rival itself removed: a removal of the target, which the rounds' own
        # re-examination tested (and the rival's split of a tie stayed in the model); an
        # extended set that keeps more parameters than the set now: a growth, which the rounds'
        # own test of an addition decides, not an exchange (module docstring)
        grown = extra is not None and parameters(trial.found) > parameters(state.found)
        if cand.name in dropped or extra in dropped or grown:
            state.simulations += trial.simulations
            return None
        gain = score(ctx, state, trial)
    else:
        dropped = ()
    state.simulations += trial.simulations
    target = fitted.target.name
    ctx.progress(
        f"  {cand.name} for {target}"
        + (f" with {extra}" if extra else "")
        + (f" (without {', '.join(dropped)})" if dropped else "")
        + f": cost {state.cost:.4g} -> {trial.cost:.4g}, score {gain:+.3g}"
    )
    return Swap(out=target, into=cand.name, state=trial, score=gain, dropped=dropped, extra=extra)


def _fitted_in(
    base: State,
    quiet: Context,
    meas: Measured,
    cand: Candidate,
    free: list[FreeParameter],
    counter: State,
) -> State | None:
    """`base` with `cand` fitted in together with the parameters `free`, exactly as a round
    fits a candidate (analysis.trials), None if it is no finding there (rounds.no_finding); the
    fit's simulations count in `counter`, the new state's own count starts at 0."""
    tried = try_candidate(base.doc, free, cand, quiet.drive, meas, quiet.opts.max_evaluations)
    if isinstance(tried, str):
        return None
    edit, alone, new_twin, result = tried
    counter.simulations += result.evaluations
    if not result.converged or no_finding(base, quiet, cand, edit, alone, result) is not None:
        return None
    trial = dataclasses.replace(base, found=list(base.found), simulations=0)
    verdict = compare(
        quiet.channels(base.outputs), quiet.channels(result.outputs), added=edit.added
    )
    adopt(
        trial, quiet, cand, edit=edit, alone=alone, new_twin=new_twin, result=result,
        explained_by=verdict.explained,
    )  # fmt: skip
    return trial


def _extended(
    state: State, ctx: Context, meas: Measured, trial: State, target: Found
) -> State | None:
    """The swapped set `trial` with one more effect, as one more round would take it (module
    docstring): the library ranked on its residual (not the target, nor an effect in the set),
    its rivals (rounds.choose_rivals) each fitted in with the set's parameters, the
    best-scoring one that the test keeps there (analysis.significance); None if none. The fits'
    simulations count in `state`."""
    exclude = tuple({f.name for f in trial.found} | {target.name})
    worth = [c for c in ranked(ctx, trial.outputs, exclude) if c.worth_fitting]
    best: tuple[float, State] | None = None
    for cand in choose_rivals(worth, ctx.opts) if worth else []:
        extended = _fitted_in(trial, _quiet(ctx), meas, cand, trial.found_free(), state)
        if extended is None:
            continue
        verdict = compare(
            ctx.channels(trial.outputs),
            ctx.channels(extended.outputs),
            added=extended.found[-1].added,
            own=cand.residual_domain,
            support=cand.support,
        )
        gain = score(ctx, state, extended)
        if verdict.significant and (best is None or gain > best[0]):
            extended.simulations = trial.simulations
            best = (gain, extended)
    return None if best is None else best[1]


# passes over the searched effects at most (analysis.joint.searched_again)
SEARCH_PASSES = 3


def searched_again(state: State, ctx: Context, meas: Measured) -> list[str]:
    """Search the found effects' searched parameters again (a record's delays, a current-offset
    ripple, a delay in ticks: no least-squares parameters, so no joint re-fit moves them), each
    with the others at their values now, in turn, until none moves (SEARCH_PASSES at most).
    Each was searched once, in its round, with the effects found after it still missing: an
    effort delay searched beside a current-offset ripple fitted without it took 2.5 ms for 2
    (the ripple's phase took the rest), and the ripple then stayed 30 % small. Returns the
    changes in words (also notes)."""
    said: list[str] = []
    for _ in range(SEARCH_PASSES):
        moved = False
        for found in [f for f in state.found if not f.own and removable([f], state.doc)]:
            ranking = {c.name: c for c in ranked(ctx, state.outputs, ())}
            cand = ranking.get(found.name)
            if cand is None:
                continue
            try:
                edit = cand.effect.edit(state.doc, cand)
            except LookupError:
                continue
            twin = Twin.compile(model_of(edit.doc))
            result = grid_search(twin, edit, ctx.drive, meas)
            state.simulations += result.evaluations
            if not result.converged or not result.cost < state.cost * (1.0 - 1e-9):
                continue
            doc = model_of(edit.doc)
            for name, value in result.values.items():
                doc = doc.set(name, value)
            before = {k: state.doc.get(k) for k in result.values}
            state.doc, state.twin = doc, Twin.compile(doc)
            state.outputs, state.cost = result.outputs, result.cost
            words = f"{found.name} searched again with the other effects in: " + ", ".join(
                f"{k} {before[k]:.4g} -> {v:.4g}" for k, v in result.values.items()
            )
            said.append(words)
            ctx.notes.append(words)
            ctx.progress(f"  {words}")
            moved = True
        if not moved:
            break
    return said
