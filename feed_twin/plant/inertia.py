"""Rotating rigid body.

Equation: J * d(omega)/dt = sum of the torques into its flange. The body owns no code of its own:
the assembler merges it into the generalized coordinate of its flange, where its inertia adds
J * r^2 to the coordinate's effective inertia.
Port: `flange` (rotational: phi [rad], omega [rad/s], tau [N m] into the flange).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_positive
from feed_twin.plant.component import Component, InertiaSpec


@dataclass(frozen=True, kw_only=True)
class Inertia(Component):
    TYPE = "Inertia"
    PORTS = {"flange": "rotational"}

    J: float  # moment of inertia [kg m^2]

    def __post_init__(self) -> None:
        require_positive("J", self.J)

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="J"),)
