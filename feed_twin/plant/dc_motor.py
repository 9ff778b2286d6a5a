"""Permanent-magnet DC motor fed by a linear power amplifier.

Equations: u = clip(gain * effort_cmd, -u_max, u_max) while the drive is enabled, else 0;
    L di/dt = u - R*i - k*omega,   tau = k*i - (T_c*sgn(omega/omega_reg) + b*omega),
with k the torque constant (= back-EMF constant in SI). The amplifier delivers u*i; copper loss
R*i^2, friction loss; magnetic energy L*i^2/2.
Port: `flange` (rotational: phi [rad], omega [rad/s], tau [N m]).
"""

from __future__ import annotations

from dataclasses import dataclass

from numba import njit

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, InertiaSpec, SlotReader, StateSpec


@njit(error_model="numpy", forceinline=True)
def dc_motor(
    effort: float,
    enabled: float,
    i: float,
    omega: float,
    gain: float,
    u_max: float,
    R: float,
    L: float,
    k: float,
) -> tuple[float, float, float]:
    """(di/dt, electromagnetic torque [N m], terminal voltage [V])."""
    u = min(max(gain * effort, -u_max), u_max) if enabled > 0.5 else 0.0
    return (u - R * i - k * omega) / L, k * i, u


@dataclass(frozen=True, kw_only=True)
class DcMotor(Component):
    TYPE = "DcMotor"
    PORTS = {"flange": "rotational"}

    R: float  # armature resistance [ohm]
    L: float  # armature inductance [H]
    k: float  # torque constant [N m/A] = back-EMF constant [V s/rad]
    J: float  # rotor inertia [kg m^2]
    T_c: float  # Coulomb friction torque [N m]
    b: float  # viscous friction [N m s/rad]
    omega_reg: float  # regularisation speed of the friction sign [rad/s]
    gain: float  # amplifier gain [V per drive input unit]
    u_max: float  # amplifier voltage limit [V]
    i_max: float  # current magnitude counted as a runaway [A]

    def __post_init__(self) -> None:
        for name in ("R", "L", "k", "J", "omega_reg", "gain", "u_max", "i_max"):
            require_positive(name, getattr(self, name))
        require_nonnegative("T_c", self.T_c)
        require_nonnegative("b", self.b)

    def states(self) -> tuple[StateSpec, ...]:
        return (StateSpec(name="i", unit="A", limit=self.i_max),)

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="J"),)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"flange": slot("T_c") / slot("omega_reg") + slot("b")}

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, omega = g.across("flange")
        di, tau, u, tau_f = g.local("di"), g.local("tau"), g.local("u"), g.local("tau_f")
        g.call(
            (di, tau, u),
            "feed_twin.plant.dc_motor.dc_motor",
            (g.drive("OUT_EFFORT_CMD"), g.drive("OUT_ENABLED"), g.x("i"), omega)
            + tuple(g.p(n) for n in ("gain", "u_max", "R", "L", "k")),
        )
        g.call(
            (tau_f,),
            "feed_twin.plant.guide_friction.friction_force",
            (omega, g.p("T_c"), g.p("T_c"), g.p("b"), g.p("b"), "0.0", "1.0", g.p("omega_reg")),
        )
        g.d("i", di)
        g.apply("flange", f"{tau} - {tau_f}")
        g.aux("tau_e", tau)
        g.aux("u", u)
        g.power("source", "amplifier", f"{u} * {g.x('i')}")
        g.power("loss", "copper", f"{g.p('R')} * {g.x('i')} ** 2")
        g.power("loss", "friction", f"{tau_f} * {omega}")
        g.stored("magnetic", f"0.5 * {g.p('L')} * {g.x('i')} ** 2")
