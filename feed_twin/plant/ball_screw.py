"""Ideal ball-screw transformer with a direction-dependent efficiency.

Kinematics: s_trans = r * phi_rot with r = lead / (2*pi) [m/rad]. The assembler merges both
flanges into one coordinate (rigid transformer), so the ratio is exact and costs nothing.
Efficiency: let F be the force the rest of the chain applies at the translational flange and v its
velocity. When the screw drives the load (F*v < 0) the rotary side must deliver |F*v|/eta; when the
load back-drives the screw (F*v > 0) only eta*F*v arrives. The factor switches smoothly,
    c = (1/eta + eta)/2 + (1/eta - eta)/2 * sgn(-F*v / P_REG),
and the generalized force of the translational flange is r*c*F; the loss (1 - c)*F*v is >= 0.
P_REG = 1 mW keeps the switch smooth without changing the loss of any real move.
Because F must be known explicitly, a lossy screw (eta < 1) needs its translational flange to be
massless: a compliance (AxialCompliance) must sit between the screw and the nut mass.
Ports: `rot` (rotational: phi [rad], tau [N m]), `trans` (translational: s [m], f [N]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numba import njit

from feed_twin.core.smooth import smooth_sign
from feed_twin.core.validate import require_positive, require_range
from feed_twin.plant.component import Component, Emitter, SlotSpec

P_REG = 1e-3  # power scale of the smooth direction switch [W]


@njit(error_model="numpy", forceinline=True)
def efficiency_factor(force: float, velocity: float, eta: float) -> tuple[float, float]:
    """(factor c applied to the force, loss power [W]) for a transformer of efficiency eta."""
    power = force * velocity
    mean = 0.5 * (1.0 / eta + eta)
    half = 0.5 * (1.0 / eta - eta)
    c = mean + half * smooth_sign(-power, P_REG)
    return c, (1.0 - c) * power


@dataclass(frozen=True, kw_only=True)
class BallScrew(Component):
    TYPE = "BallScrew"
    PORTS = {"rot": "rotational", "trans": "translational"}
    COMPUTED_SLOTS = {"ratio": SlotSpec(unit="m/rad", low=0.0, low_open=True)}  # lead / 2 pi
    TRANSFORMER = ("rot", "trans", "ratio")  # across(trans) = p[ratio] * across(rot)

    lead: float  # travel per screw revolution [m]
    efficiency: float  # mechanical efficiency of the nut, in (0, 1] [1]

    def __post_init__(self) -> None:
        require_positive("lead", self.lead)
        require_range("efficiency", self.efficiency, 1e-3, 1.0)

    @property
    def lossy(self) -> bool:
        return self.efficiency < 1.0

    def slots(self) -> dict[str, float]:
        return {"ratio": self.lead / (2.0 * math.pi), "efficiency": self.efficiency}

    def force_per_torque(self, *, resisting: bool) -> float:
        """Force at the nut [N] that one newton metre at the screw balances: 2 pi / (lead c).

        `resisting`: the force resists every motion (friction), so the screw always drives the
        load and c = 1/eta (force per torque 2 pi eta / lead). Otherwise the force is driven
        against as often as it drives (inertia over a move that brakes as hard as it
        accelerates, a weight lifted and lowered, a force held at rest): c takes its mean
        (1/eta + eta)/2, the factor of efficiency_factor at zero power.
        """
        mean = 0.5 * (1.0 / self.efficiency + self.efficiency)
        half = 0.5 * (1.0 / self.efficiency - self.efficiency)
        c = mean + half if resisting else mean
        return 2.0 * math.pi / (self.lead * c)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "transmit" and self.lossy:
            _, v = g.across("trans")
            c, loss = g.local("c"), g.local("loss")
            g.call(
                (c, loss),
                "feed_twin.plant.ball_screw.efficiency_factor",
                (g.node_force("trans"), v, g.p("efficiency")),
            )
            g.scale_node("trans", c)
            g.power("loss", "efficiency", loss)
