"""Forces from outside the drive: a sampled input (cutting force) and a constant force.

ExternalForce: f = f_ext(t) into the flange, where f_ext is the engine input channel named after
the component (held over each base tick). ConstantForce: f = f_0 (a load, a cable, the offset of
the EMPS reference model). Both report the work they do on the axis, f*v, as a source power.
Port: `flange` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from feed_twin.core.validate import require_finite
from feed_twin.plant.component import Component, Emitter
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    Weights,
    free_parameter,
    make_edit,
    symmetric,
)


def _emit_force(g: Emitter, f: str) -> None:
    _, v = g.across("flange")
    g.apply("flange", f)
    g.aux("force", f)
    g.power("source", "work", f"{f} * {v}")


@dataclass(frozen=True, kw_only=True)
class ExternalForce(Component):
    TYPE = "ExternalForce"
    PORTS = {"flange": "translational"}
    HAS_INPUT = True

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            _emit_force(g, g.ext())


def with_constant_force(doc: Document, f_0: float) -> tuple[Document, str]:
    """The document with a ConstantForce f_0 [N] on the table (or its own set); (doc, slot)."""
    existing = doc.of_type(ConstantForce.TYPE)
    if existing:
        return doc.set(f"{existing[0]}.f_0", f_0), f"{existing[0]}.f_0"
    params = {"f_0": float(f_0)}
    doc, name = doc.with_table_component("constant_force", ConstantForce.TYPE, params)
    return doc, f"{name}.f_0"


def _constant_edit(doc: Document, cand: Weights) -> Edit:
    """A ConstantForce on the table (or the model's own) with f_0 fitted."""
    # the residual is measured minus twin: a force the drive must supply is a load of -f_0
    f0 = -cand.force("one")
    doc, slot = with_constant_force(symmetric(doc), f0)
    own = [free_parameter(doc, slot, f0, lower=-math.inf)]
    return make_edit(doc, own, {"f_0_N": lambda v: v[slot]})


def _constant_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return with_constant_force(doc, p["f_0_N"])[0]


@dataclass(frozen=True, kw_only=True)
class ConstantForce(Component):
    TYPE = "ConstantForce"
    PORTS = {"flange": "translational"}
    EFFECTS = (
        Effect(
            name="constant_force",
            domain="effort",
            words="a constant force in one direction (gravity on a vertical axis, an unbalanced "
            "counterweight, an offset in the force measurement)",
            parameters="f_0",
            signature=lambda m: {"one": np.ones_like(m.t_s)},
            edit=_constant_edit,
            truth=_constant_truth,
        ),
    )

    f_0: float  # force into the flange [N]

    def __post_init__(self) -> None:
        require_finite("f_0", self.f_0)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            _emit_force(g, g.p("f_0"))
