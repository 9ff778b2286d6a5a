"""Cogging torque on a rotor flange: one harmonic of a torque that repeats per revolution.

Equation: tau = A sin(n phi + phase) into the flange (n periods per mechanical revolution),
the gradient of the potential -A/n cos(n phi + phase): Pmsm's cogging harmonic
(plant.pmsm.cogging) as a component of its own, for a twin whose motor is an EffortSource on
an Inertia (a drive behind its current loop: no rotor model to carry it, but the rotor angle is
the flange's). The discrepancy workflow adds one on the effort source's flange where the model
has no Pmsm (plant.pmsm.with_cogging).
Port: `flange` (rotational: phi [rad], omega [rad/s], tau [N m] into the flange).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_finite, require_nonnegative
from feed_twin.plant.component import Component, Emitter


@dataclass(frozen=True, kw_only=True)
class CoggingTorque(Component):
    TYPE = "CoggingTorque"
    PORTS = {"flange": "rotational"}

    order: int  # periods per mechanical revolution [1]
    amplitude: float  # torque amplitude A [N m]
    phase: float  # phase at phi = 0 [rad]

    def __post_init__(self) -> None:
        if self.order < 1:
            raise ValueError(f"order = {self.order!r}: must be a whole number >= 1")
        require_nonnegative("amplitude", self.amplitude)
        require_finite("phase", self.phase)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        phi, _ = g.across("flange")
        tau, v = g.local("tau"), g.local("v")
        g.call(
            (tau, v),
            "feed_twin.plant.pmsm.cogging",
            (phi, g.p("order"), g.p("amplitude"), g.p("phase")),
        )
        g.apply("flange", tau)
        g.aux("torque", tau)
        g.stored("cogging", v)
