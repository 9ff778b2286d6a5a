"""Backlash: a dead-zone spring-damper (no force inside the gap, stiff contact outside).

Equation: with delta = s_a - s_b and half gap b = gap/2,
    f_e = k * (delta - b) if delta > b,  k * (delta + b) if delta < -b,  else 0,
    f = f_e + d * (v_a - v_b) in contact, limited so that f never changes the sign of f_e
(a contact can push, never pull: without the limit the damper would glue the faces together
while they separate). f is passed from a to b (-f into a, +f into b). Stored energy
k*(|delta| - b)^2/2 in contact, loss (f - f_e)*(v_a - v_b).
Ports: `a`, `b` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotReader
from feed_twin.plant.coupling import emit_two_port
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Weights,
    last_direction,
    make_edit,
)


@njit(error_model="numpy", forceinline=True)
def backlash_force(
    delta: float, delta_rate: float, gap: float, k: float, d: float
) -> tuple[float, float, float]:
    """(cut force a->b, stored energy, loss power) of a dead-zone contact."""
    half = 0.5 * gap
    if delta > half:
        f_e = k * (delta - half)
        f = max(f_e + d * delta_rate, 0.0)
    elif delta < -half:
        f_e = k * (delta + half)
        f = min(f_e + d * delta_rate, 0.0)
    else:
        return 0.0, 0.0, 0.0
    return f, 0.5 * f_e * f_e / k, (f - f_e) * delta_rate


def _last_direction(m: Motion) -> dict[str, FloatArray]:
    return {"last_direction": last_direction(m)}


def gap_slot(doc: Document) -> str:
    """The slot that carries the lost motion between nut and table: the model's Backlash gap,
    else the gap of an AxialCompliance whose parameters declare one (the nut's lost motion in
    series with the screw's spring, no nut mass: plant.axial_compliance); a LookupError says
    what the model lacks."""
    found = doc.of_type(Backlash.TYPE)
    if found:
        return f"{found[0]}.gap"
    for name in doc.of_type("AxialCompliance"):
        if "gap" in doc.component(name).get("params", {}):
            return f"{name}.gap"
    raise LookupError(
        "the model has no Backlash between a nut mass and the table, nor an AxialCompliance "
        "that declares the nut's gap, to carry the gap"
    )


def _gap_edit(doc: Document, cand: Weights) -> Edit:
    """The gap of the model's Backlash (lost motion between nut and table) is fitted.

    A move in +x leaves the table b = gap/2 behind the nut, a move in -x b ahead, so the
    position residual (twin minus measured) is (gap_true - gap_model)/2 * last direction.
    """
    slot = gap_slot(doc)
    nominal = doc.get(slot)
    guess = max(nominal + 2.0 * cand.coefficients.get("last_direction", 0.0), 1e-7)
    doc = doc.set(slot, guess)
    own = [FreeParameter(name=slot, initial=guess, scale=guess, lower=0.0)]
    return make_edit(doc, own, {"gap_m": lambda v: v[slot]}, interacts=False)


def _gap_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return doc.set(gap_slot(doc), p["gap_m"])


@dataclass(frozen=True, kw_only=True)
class Backlash(Component):
    TYPE = "Backlash"
    PORTS = {"a": "translational", "b": "translational"}
    STATE_OUTPUTS = {"screw_force": "force"}  # the nut's push on the table
    EFFECTS = (
        Effect(
            name="backlash",
            domain="position",
            words="lost motion at every reversal: the table stays behind by a fixed gap when "
            "the direction changes",
            parameters="gap",
            signature=_last_direction,
            edit=_gap_edit,
            truth=_gap_truth,
        ),
    )

    gap: float  # total clearance [m]
    k: float  # contact stiffness [N/m]
    d: float  # contact damping [N s/m]

    def __post_init__(self) -> None:
        require_nonnegative("gap", self.gap)
        require_positive("k", self.k)
        require_nonnegative("d", self.d)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"a": slot("d"), "b": slot("d")}

    def stiffness_bound(self, slot: SlotReader) -> float:
        return slot("k")

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            emit_two_port(
                g, "feed_twin.plant.backlash.backlash_force", (g.p("gap"), g.p("k"), g.p("d"))
            )
