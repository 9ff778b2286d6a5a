"""Forces from outside the drive: a sampled input (cutting force) and a constant force.

ExternalForce: f = f_ext(t) into the flange, where f_ext is the engine input channel named after
the component (held over each base tick). ConstantForce: f = f_0 (a load, a cable, the offset of
the EMPS reference model). Both report the work they do on the axis, f*v, as a source power.
Port: `flange` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.io.config import require_finite
from feed_twin.plant.component import Component, Emitter


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


@dataclass(frozen=True, kw_only=True)
class ConstantForce(Component):
    TYPE = "ConstantForce"
    PORTS = {"flange": "translational"}

    f_0: float  # force into the flange [N]

    def __post_init__(self) -> None:
        require_finite("f_0", self.f_0)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            _emit_force(g, g.p("f_0"))
