"""Ball-screw shaft in torsion: distributed inertia lumped at both ends, one torsional spring.

Equation: tau = k_t * (phi_a - phi_b) + d * (omega_a - omega_b) passed from end a (drive side) to
end b (nut side), with the solid-shaft values
    k_t = G * pi * d_root^4 / (32 * length),   J = rho * pi * d_nominal^4 * length / 32,
and J/2 lumped at each end (the two-mass approximation of the first torsional mode). The core
(root diameter) carries the torsion; the inertia counts the thread lands too, which the nominal
diameter approximates (catalogues quote J from it).
Ports: `a`, `b` (rotational: phi [rad], omega [rad/s], tau [N m]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, InertiaSpec, SlotReader, SlotSpec
from feed_twin.plant.coupling import emit_two_port


@dataclass(frozen=True, kw_only=True)
class ScrewShaft(Component):
    TYPE = "ScrewShaft"
    PORTS = {"a": "rotational", "b": "rotational"}
    COMPUTED_SLOTS = {
        "k_t": SlotSpec(unit="N m/rad", low=0.0, low_open=True),  # G pi d_root^4 / (32 length)
        "J": SlotSpec(unit="kg m^2", low=0.0, low_open=True),  # rho pi d_nominal^4 length / 32
    }

    d_root: float  # root (core) diameter of the screw [m]
    d_nominal: float  # nominal diameter of the screw [m]
    length: float  # length between the drive-side bearing and the nut [m]
    G: float  # shear modulus [Pa] (steel about 80e9)
    rho: float  # density [kg/m^3] (steel about 7850)
    d: float  # torsional damping [N m s/rad]

    def __post_init__(self) -> None:
        require_positive("d_root", self.d_root)
        require_positive("d_nominal", self.d_nominal)
        require_positive("length", self.length)
        require_positive("G", self.G)
        require_positive("rho", self.rho)
        require_nonnegative("d", self.d)

    def slots(self) -> dict[str, float]:
        return {
            "k_t": self.G * math.pi * self.d_root**4 / 32.0 / self.length,
            "J": self.rho * math.pi * self.d_nominal**4 / 32.0 * self.length,
            "d": self.d,
        }

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (
            InertiaSpec(port="a", slot="J", factor=0.5),
            InertiaSpec(port="b", slot="J", factor=0.5),
        )

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"a": slot("d"), "b": slot("d")}

    def stiffness_bound(self, slot: SlotReader) -> float:
        return slot("k_t")

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            emit_two_port(g, "feed_twin.plant.coupling.spring_damper", (g.p("k_t"), g.p("d")))
