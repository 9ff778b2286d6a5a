"""Re-examining the effects found earlier, once a later one has been added.

An effect found first soaks up part of one that overlaps it (a constant force fitted before a
direction-dependent friction takes the mean of the two directions): with the second in the
model, the first may no longer be needed. After each addition every earlier effect is
examined jointly with the others:
- its parameters collapsed: every size parameter moved back to within COLLAPSE of the value
  that removes the effect (its `neutral` value: the model's value before the effect was added,
  0 for a component the effect added) -- dropped without further ado;
- otherwise it is removed (its parameters set to neutral), the others are fitted again without
  it, and the likelihood-ratio test of analysis.significance decides whether the model with it
  is significantly better; if not, removing it costs nothing and it is dropped.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from feed_twin.analysis.fit import FitResult, FreeParameter, Measured, SimOutputs, fit
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.significance import Verdict, compare
from feed_twin.analysis.twin import Drive, ModelDoc, Twin

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


def collapsed(found: Found, doc: ModelDoc) -> bool:
    values = {s: doc.get(s) for s in found.neutral if doc.has_slot(s)}
    return fell_back(found.neutral, found.at_discovery, values)


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
    """Remove `target` from `doc`, fit the others again; None if the simulation fails."""
    for slot, value in target.neutral.items():
        doc = doc.set(slot, value)
    free = [
        dataclasses.replace(p, initial=doc.get(p.name))
        for f in others
        for p in f.own
        if doc.has_slot(p.name) and p.name not in target.neutral
    ]
    twin = Twin.compile(doc)
    if free:
        result: FitResult = fit(
            lambda params: twin.simulate(drive, params),
            twin.nominal,
            twin.index,
            free,
            meas,
            max_evaluations=max_evaluations,
        )
        for name, value in result.values.items():
            doc = doc.set(name, value)
        twin = Twin.compile(doc)
        out = result.outputs
    else:
        out = twin.simulate(drive, twin.nominal[None, :])
    if not out.ok[0]:
        return None
    verdict = compare(channels(out), channels(outputs), added=target.added)
    return Without(doc=doc, twin=twin, outputs=out, verdict=verdict)
