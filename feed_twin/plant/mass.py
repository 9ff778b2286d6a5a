"""Translating rigid body (table, nut, carriage).

Equation: m * dv/dt = sum of the forces into its flange; merged by the assembler into the
coordinate of its flange, where it adds m * r^2 to the effective inertia.
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from feed_twin.core.validate import require_positive
from feed_twin.plant.component import Component, InertiaSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Weights,
    make_edit,
    slot_reader,
    symmetric,
)


def _table_mass(doc: Document) -> str:
    m = doc.mass_slot()
    if m is None:
        raise LookupError("the model has no Mass component")
    return m


def _mass_edit(doc: Document, cand: Weights) -> Edit:
    m = _table_mass(doc)
    doc = symmetric(doc)
    value = doc.get(m)
    guess = max(value + cand.force("a"), 0.2 * value)
    doc = doc.set(m, guess)
    own = [FreeParameter(name=m, initial=guess, scale=value, lower=0.2 * value)]
    return make_edit(doc, own, {"m_kg": slot_reader(m)})


def _mass_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return doc.set(_table_mass(doc), p["m_kg"])


@dataclass(frozen=True, kw_only=True)
class Mass(Component):
    TYPE = "Mass"
    PORTS = {"flange": "translational"}
    EFFECTS = (
        Effect(
            name="mass_error",
            domain="effort",
            words="a force proportional to acceleration: the moving mass differs from the model",
            parameters="m",
            signature=lambda m: {"a": m.a_m_s2},
            edit=_mass_edit,
            truth=_mass_truth,
        ),
    )

    m: float  # mass [kg]

    def __post_init__(self) -> None:
        require_positive("m", self.m)

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="m"),)
