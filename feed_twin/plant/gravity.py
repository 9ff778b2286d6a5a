"""Gravity on an inclined or vertical axis, with an optional counterweight.

Equation: f = -(m - m_counterweight) * g * sin(incline) into the flange, where incline is the
angle of the positive axis direction above the horizontal (90 deg: vertical, positive up). The
counterweight hangs on a chain over a pulley: it moves rigidly with the slide, so it adds its mass
to the flange's inertia. Potential energy (m - m_counterweight)*g*sin(incline)*s.
Port: `flange` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from feed_twin.core.validate import require_nonnegative, require_positive, require_range
from feed_twin.plant.component import Component, Emitter, InertiaSpec, SlotSpec


@dataclass(frozen=True, kw_only=True)
class Gravity(Component):
    TYPE = "Gravity"
    PORTS = {"flange": "translational"}
    COMPUTED_SLOTS = {"weight": SlotSpec(unit="N")}  # along the axis, either sign

    m: float  # mass the gravity pulls on (slide + workpiece) [kg]
    g: float  # gravitational acceleration [m/s^2]
    incline_deg: float  # angle of the positive axis direction above the horizontal [deg]
    m_counterweight: float  # counterweight mass [kg], 0 for none

    def __post_init__(self) -> None:
        require_positive("m", self.m)
        require_positive("g", self.g)
        require_range("incline_deg", self.incline_deg, -90.0, 90.0)
        require_nonnegative("m_counterweight", self.m_counterweight)

    def slots(self) -> dict[str, float]:
        weight = (self.m - self.m_counterweight) * self.g * math.sin(math.radians(self.incline_deg))
        return {"weight": weight, "m_counterweight": self.m_counterweight}

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="m_counterweight"),)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        s, _ = g.across("flange")
        g.apply("flange", f"-{g.p('weight')}")
        g.stored("potential", f"{g.p('weight')} * {s}")
