"""Re-examining the effects found earlier, once a later one has been added.

An effect found first soaks up part of one that overlaps it (a constant force fitted before a
direction-dependent friction takes the mean of the two directions): with the second in the
model, the first may no longer be needed. After each addition every earlier effect is
examined jointly with the others:
- its parameters collapsed: every size parameter moved back to within COLLAPSE of the value
  that removes the effect (its `neutral` value: the model's value before the effect was added,
  0 for a component the effect added) -- dropped without further ado. An effect that split a
  tied forward/backward pair (asymmetric friction) is removed by tying the pair again at its
  mean: its size is each member's distance from that mean, whatever the later fits did to the
  mean (a later law that took over the Coulomb part). An effect whose tie a later one split
  (Coulomb friction, once asymmetric) is read as the mean of the tie's members and removed by
  setting each member to its neutral value;
- otherwise it is removed (its parameters set to neutral), the others are fitted again without
  it, and the likelihood-ratio test of analysis.significance decides whether the model with it
  is significantly better; if not, removing it costs nothing and it is dropped. A searched
  effect (a record delay, the trace's window: no least-squares parameters) is examined alike:
  a 4.5 ms effort delay fitted first on a 50 Hz averaged trace made the effort 6x worse once
  the trace's window was in, and stayed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from feed_twin.analysis.fit import FitResult, FreeParameter, Measured, SimOutputs
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.significance import Verdict, compare
from feed_twin.analysis.trials import fit_resumed
from feed_twin.analysis.twin import Drive, ModelDoc, Twin
from feed_twin.core.config import ConfigError

COLLAPSE = 0.1  # share of its size at discovery below which a fitted effect has collapsed

Channels = Callable[[SimOutputs], dict[str, np.ndarray]]  # simulation -> channel residuals


@dataclass(frozen=True, kw_only=True)
class Found:
    """An effect in the model, with what it takes to remove it again."""

    effect: FoundEffect
    own: tuple[FreeParameter, ...]  # its least-squares parameters (empty: a searched grid)
    neutral: dict[str, float]  # slot -> the value that removes the effect
    at_discovery: dict[str, float]  # slot -> its value when it was added
    report: dict[str, Callable[[dict[str, float]], float]]
    added: int  # degrees of freedom it adds
    # tied pairs the effect split (removed by tying them again at their mean)
    pairs: tuple[tuple[str, ...], ...] = ()
    # a tie slot's members (the effect is read and removed through them once a later one
    # splits the tie)
    members: Mapping[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.effect.name


def neutral_values(before: ModelDoc, after: ModelDoc, slots: tuple[str, ...]) -> dict[str, float]:
    """Each slot's value in `before` (the mean of a tie's members there), or 0 if it is new."""
    out = {}
    for slot in slots:
        members = after.tie_members(slot)
        held = [m for m in members if before.has_slot(m)]
        if before.has_slot(slot):
            out[slot] = before.get(slot)
        elif held:
            out[slot] = sum(before.get(m) for m in held) / len(held)
        else:
            out[slot] = 0.0
    return out


def _sized(slot: str) -> bool:
    """A size parameter (not a phase, which has no neutral value)."""
    return not slot.endswith("phase")


def split_pairs(before: ModelDoc, after: ModelDoc, slots: tuple[str, ...]):
    """The tied pairs of `before` whose members are all free slots of `after` (the effect with
    those slots split them), and each tie slot's members in `after`."""
    pairs = tuple(
        members
        for name, members in before.ties
        if not after.has_slot(name) and all(m in slots for m in members)
    )
    return pairs, {s: after.tie_members(s) for s in slots if s in after.tie_names()}


def _now(found: Found, doc: ModelDoc, slot: str) -> float | None:
    """The slot's value in `doc`, through its members if a later effect split its tie."""
    if doc.has_slot(slot):
        return doc.get(slot)
    members = found.members.get(slot, ())
    if members and all(doc.has_slot(m) for m in members):
        return sum(doc.get(m) for m in members) / len(members)
    return None


def _pair(found: Found, slot: str) -> tuple[str, ...] | None:
    return next((p for p in found.pairs if slot in p), None)


def _mean(values: Mapping[str, float] | ModelDoc, pair: tuple[str, ...]) -> float:
    get = values.get if isinstance(values, ModelDoc) else values.__getitem__
    return sum(get(m) for m in pair) / len(pair)


def collapsed(found: Found, doc: ModelDoc) -> bool:
    neutral, reference, values = {}, {}, {}
    for slot, zero in found.neutral.items():
        now = _now(found, doc, slot)
        if now is None:
            continue
        pair = _pair(found, slot)
        if pair is None:
            neutral[slot], reference[slot], values[slot] = zero, found.at_discovery[slot], now
        else:
            # an asymmetry: each member's distance from the pair's mean, now and at discovery
            neutral[slot] = 0.0
            reference[slot] = found.at_discovery[slot] - _mean(found.at_discovery, pair)
            values[slot] = now - _mean(doc, pair)
    return fell_back(neutral, reference, values)


def removed(found: Found, doc: ModelDoc) -> ModelDoc:
    """`doc` without the effect: each slot at its neutral value, a pair it split at the pair's
    mean, a tie a later effect split with each member at the neutral value."""
    means = {p: _mean(doc, p) for p in found.pairs if all(doc.has_slot(m) for m in p)}
    for slot, value in found.neutral.items():
        pair = _pair(found, slot)
        if pair is not None and pair in means:
            value = means[pair]
        if doc.has_slot(slot):
            doc = doc.set(slot, value)
        else:
            for member in found.members.get(slot, ()):
                doc = doc.set(member, value)
    return doc


def values_now(found: Found, doc: ModelDoc) -> str:
    """The effect's slots in `doc`, as a note lists them."""
    now = {s: _now(found, doc, s) for s in found.neutral}
    return ", ".join(f"{k} = {v:.4g}" for k, v in now.items() if v is not None)


def fell_back(
    neutral: dict[str, float], reference: dict[str, float], values: dict[str, float]
) -> bool:
    """Every size parameter in `values` lies within COLLAPSE of its distance from neutral at
    `reference` (False if there is none)."""
    sized = [s for s in values if _sized(s)]
    if not sized:
        return False
    for slot in sized:
        zero = neutral[slot]
        if abs(values[slot] - zero) > COLLAPSE * abs(reference[slot] - zero):
            return False
    return True


def removable(found: list[Found], doc: ModelDoc) -> bool:
    """True if every slot of the effect is still a slot of the model (not split by a later one)."""
    return all(doc.has_slot(s) for f in found for s in f.neutral)


@dataclass(frozen=True, kw_only=True, eq=False)
class Without:
    """The model with one effect removed and the others fitted again."""

    doc: ModelDoc
    twin: Twin
    outputs: SimOutputs
    verdict: Verdict  # the test of the model WITH the effect against this one
    simulations: int  # parameter sets simulated to find it


def without(
    target: Found,
    others: list[Found],
    doc: ModelDoc,
    outputs: SimOutputs,
    *,
    drive: Drive,
    meas: Measured,
    channels: Channels,
    max_evaluations: int,
) -> Without | None:
    """Remove `target` from `doc`, fit the others again; None if the simulation fails or the
    others' re-fit runs to a model no feed axis has (a bearing stiffness fitted to 3e61 N/m
    in place of a current-sensor offset's ripple): the model without the effect is then no
    rival, and the effect stays."""
    doc = removed(target, doc)
    free = [
        dataclasses.replace(p, initial=doc.get(p.name))
        for f in others
        for p in f.own
        if doc.has_slot(p.name) and p.name not in target.neutral
    ]
    twin = Twin.compile(doc)
    if free:
        # the same least squares as the fit that added the effect (resumed once if its budget
        # ran out on the way down): a re-fit stopped early would make the model without the
        # effect look worse than it is, and the test would keep the effect for that alone
        result: FitResult = fit_resumed(twin, drive, free, meas, max_evaluations)
        for name, value in result.values.items():
            doc = doc.set(name, value)
        try:
            twin = Twin.compile(doc)
        except ConfigError:
            return None
        out, simulations = result.outputs, result.evaluations
    else:
        out, simulations = twin.simulate(drive, twin.nominal[None, :]), 1
    if not out.ok[0]:
        return None
    verdict = compare(channels(out), channels(outputs), added=target.added)
    return Without(doc=doc, twin=twin, outputs=out, verdict=verdict, simulations=simulations)
