"""Translating rigid body (table, nut, carriage).

Equation: m * dv/dt = sum of the forces into its flange; merged by the assembler into the
coordinate of its flange, where it adds m * r^2 to the effective inertia.
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_positive
from feed_twin.plant.component import Component, InertiaSpec


@dataclass(frozen=True, kw_only=True)
class Mass(Component):
    TYPE = "Mass"
    PORTS = {"flange": "translational"}

    m: float  # mass [kg]

    def __post_init__(self) -> None:
        require_positive("m", self.m)

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="m"),)
