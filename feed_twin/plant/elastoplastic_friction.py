"""A contact that stays deflected the way it slid: elasto-plastic friction (Dupont et al.).

The asperities of the contact are a spring of deflection z that follows the table while the
force it carries is below the sliding force F_hold and slips beyond it, in the elasto-plastic
form of Dupont, Hayward, Armstrong and Altpeter (2002) with its elastic and plastic regimes
switched at z_max = F_hold / k_s (no Stribeck or speed-dependent part: F_hold is the Coulomb
force at any speed):
    dz/dt = 0 if z v > 0 and |z| >= z_max (sliding: dragged along at the limit),
            v otherwise (stuck, or backing off: deflecting with the table),
            minus r_slip (z - clip(z, -z_max, z_max)) (an RK4 stage that overshot falls back),
    F = k_s clip(z, -z_max, z_max) + d_s v [while |z| < z_max],
the flange receives -F. Unlike the Karnopp contact of StictionFriction, whose asperities let go
while sliding (caught again at its release speed carrying 30 % of F_hold), this one is never
released: a table that stops after sliding keeps its deflection, so the contact holds the
sliding force F_hold at standstill, any smaller force the drive then applies as a deflection
F / k_s, and the drive must swing its force through 2 F_hold over the presliding 2 z_max to
reverse. There is no break-away drop: the force to start is the force to slide. A drive whose
position loop carries its sliding force through a stop holds it there (an elasto-plastic or
LuGre contact that stops deflected does), which the Karnopp law cannot (docs/diagnose.md).
k_s is stiff to the step (the stuck table rings at 0.5 / h) and nothing else is stiff: the
switch pins z at the limit instead of relaxing it at |v| / z_max (r_slip h < 2.78 for explicit
RK4, r_slip h = 1 is plenty).
Stored energy k_s clip(z)^2 / 2; loss F v - k_s clip(z) d(clip z)/dt (F_hold |v| sliding, d_s
v^2 stuck, never negative).
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange). State: `z` [m], 0 at the
start (nothing held).
"""

from __future__ import annotations

from dataclasses import dataclass

from numba import njit

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotReader, StateSpec

DEFLECTION_LIMIT_M = 1e-2  # |z| above this is a runaway


@njit(error_model="numpy", forceinline=True)
def elastoplastic_force(
    z: float, v: float, F_hold: float, k_s: float, d_s: float, r_slip: float
) -> tuple[float, float, float, float]:
    """(friction force F [N], dz/dt [m/s], stored energy [J], loss power [W])."""
    z_max = F_hold / k_s
    z_c = min(max(z, -z_max), z_max)
    inside = abs(z) < z_max
    # at the limit and pushed on: dragged along; stuck or backing off: deflecting with the table
    rate = (0.0 if not inside and z * v > 0.0 else v) - r_slip * (z - z_c)
    f = k_s * z_c + (d_s * v if inside else 0.0)
    stored = 0.5 * k_s * z_c * z_c
    loss = f * v - (k_s * z_c * rate if inside else 0.0)
    return f, rate, stored, loss


@dataclass(frozen=True, kw_only=True)
class ElastoPlasticFriction(Component):
    TYPE = "ElastoPlasticFriction"
    PORTS = {"flange": "translational"}

    F_hold: float  # sliding force, held at standstill up to it [N]
    k_s: float  # presliding stiffness of the contact [N/m]
    d_s: float  # presliding damping while stuck [N s/m]
    r_slip: float  # rate at which an overshot deflection falls back [1/s]

    def __post_init__(self) -> None:
        require_nonnegative("F_hold", self.F_hold)
        require_positive("k_s", self.k_s)
        require_nonnegative("d_s", self.d_s)
        require_positive("r_slip", self.r_slip)

    def states(self) -> tuple[StateSpec, ...]:
        return (StateSpec(name="z", unit="m", limit=DEFLECTION_LIMIT_M),)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"flange": slot("d_s")}  # the presliding damping; sliding, the force is flat

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, v = g.across("flange")
        f, rate, e, loss = g.local("f"), g.local("rate"), g.local("e"), g.local("loss")
        g.call(
            (f, rate, e, loss),
            "feed_twin.plant.elastoplastic_friction.elastoplastic_force",
            (g.x("z"), v, g.p("F_hold"), g.p("k_s"), g.p("d_s"), g.p("r_slip")),
        )
        g.d("z", rate)
        g.apply("flange", f"-{f}")
        g.aux("force", f)
        g.stored("asperities", e)
        g.power("loss", "friction", loss)
