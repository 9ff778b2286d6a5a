"""How far to trust the final model: intervals, correlations, implausible values and drift.

Run once on the final model (after the joint re-fit): the sensitivities of the normalised
residuals to every parameter the joint fit frees (the found effects' and the nominal ones they
interact with) in one batch of the engine (analysis.uncertainty), from which
- each fitted parameter's 95 % interval and each found effect's reported parameters' ones;
- the pairs whose estimates are strongly correlated (the record fixes their combination);
- the values no machine of the model's kind would have, with their likely cause
  (analysis.plausible);
- the parameters that drift over the record, with their rate (analysis.drift).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feed_twin.analysis.channels import weighted_channels
from feed_twin.analysis.drift import drifts
from feed_twin.analysis.plausible import implausible
from feed_twin.analysis.rounds import Context, State, Values, joint_free
from feed_twin.analysis.twin import ModelDoc
from feed_twin.analysis.uncertainty import Z95, Estimates, estimates, sensitivity


@dataclass(frozen=True, kw_only=True)
class Appraisal:
    # slot -> {nominal, value, low, high} (95 %)
    parameters: dict[str, dict[str, float]] = field(default_factory=dict)
    correlated: tuple[dict[str, Any], ...] = ()  # {a, b, correlation}
    implausible: tuple[str, ...] = ()
    drifts: tuple[dict[str, Any], ...] = ()
    simulations: int = 0
    seconds: float = 0.0
    note: str = ""  # why there is no appraisal ("" if there is one)

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def lines(self) -> list[str]:
        """report.md's lines."""
        out = [
            f"- {slot}: {p['value']:.5g} (95 % interval {p['low']:.5g} .. {p['high']:.5g}; "
            f"nominal {p['nominal']:.5g})"
            for slot, p in self.parameters.items()
        ]
        out += [
            f"- correlated: {c['a']} and {c['b']} ({c['correlation']:+.3f}): the record fixes "
            "their combination, not each"
            for c in self.correlated
        ]
        out += [f"- implausible: {flag}" for flag in self.implausible]
        out += [f"- drift: {d['words']}" for d in self.drifts]
        if self.note:
            out.append(f"- {self.note}")
        out.append(
            f"- cost: {self.simulations} simulations, {self.seconds:.2f} s (sensitivities in "
            "one batch)"
        )
        return out


def appraise(state: State, ctx: Context, nominal: ModelDoc) -> Appraisal:
    """The appraisal of `state`'s model; its found effects get their intervals."""
    clock = time.perf_counter()
    free = joint_free(state)
    if not free:
        return Appraisal(note="no fitted parameter to appraise")
    meas = weighted_channels(ctx.run, state.outputs, ctx.stride, ctx.floors, start=ctx.start)
    s = sensitivity(state.twin, ctx.drive, free, meas, ctx.run.t_s)
    if s is None:
        return Appraisal(note="a perturbed simulation diverged: no intervals")
    est = estimates(s)
    _intervals_of_effects(state, est)
    sigma = est.sigma
    parameters = {
        name: {
            "nominal": nominal.get(name) if nominal.has_slot(name) else 0.0,
            "value": float(v),
            "low": float(v - Z95 * sd),
            "high": float(v + Z95 * sd),
        }
        for name, v, sd in zip(est.names, est.values, sigma, strict=True)
    }
    pairs = est.correlated()
    partners: dict[str, list[str]] = {}
    for a, b, _ in pairs:
        partners.setdefault(a, []).append(b)
        partners.setdefault(b, []).append(a)
    flags = implausible(
        nominal,
        state.doc,
        est.names,
        [f.effect for f in state.found],
        v_max_m_s=float(np.max(np.abs(ctx.motion.v_m_s))),
        correlated=partners,
        owned=[p.name for f in state.found for p in f.own],
    )
    return Appraisal(
        parameters=parameters,
        correlated=tuple({"a": a, "b": b, "correlation": rho} for a, b, rho in pairs),
        implausible=tuple(flags),
        drifts=tuple(d.as_dict() for d in drifts(s)),
        simulations=s.simulations,
        seconds=time.perf_counter() - clock,
    )


def _intervals_of_effects(state: State, est: Estimates) -> None:
    for k, f in enumerate(state.found):
        intervals = {}
        for name, of in f.report.items():
            _, low, high = est.interval(of, Values(state.doc))
            intervals[name] = (low, high)
        state.found[k] = dataclasses.replace(
            f, effect=dataclasses.replace(f.effect, intervals=intervals)
        )
