"""Torsional spring-damper (flexible coupling) and the spring-damper law other elements reuse.

Equation: the cut torque passed from flange a to flange b is
    tau = k * (phi_a - phi_b) + d * (omega_a - omega_b),
applied as -tau into a and +tau into b. Stored energy k*(phi_a - phi_b)^2/2, dissipated power
d*(omega_a - omega_b)^2.
Ports: `a`, `b` (rotational: phi [rad], omega [rad/s], tau [N m]).
"""

from __future__ import annotations

from dataclasses import dataclass

from numba import njit

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotReader


@njit(error_model="numpy", forceinline=True)
def spring_damper(
    delta: float, delta_rate: float, k: float, d: float
) -> tuple[float, float, float]:
    """(cut force, stored energy, dissipated power) of a linear spring-damper."""
    damping = d * delta_rate
    return k * delta + damping, 0.5 * k * delta * delta, damping * delta_rate


def emit_two_port(g: Emitter, func: str, params: tuple[str, ...]) -> None:
    """Glue of a two-port element on ports a, b whose law is
    `func(delta, delta_rate, *params) -> (cut force a->b, stored energy, loss power)`."""
    s_a, v_a = g.across("a")
    s_b, v_b = g.across("b")
    f, e, loss = g.local("f"), g.local("e"), g.local("loss")
    g.call((f, e, loss), func, (f"{s_a} - {s_b}", f"{v_a} - {v_b}", *params))
    g.apply("a", f"-{f}")
    g.apply("b", f)
    g.aux("force", f)
    g.stored("spring", e)
    g.power("loss", "damping", loss)


@dataclass(frozen=True, kw_only=True)
class Coupling(Component):
    TYPE = "Coupling"
    PORTS = {"a": "rotational", "b": "rotational"}

    k: float  # torsional stiffness [N m/rad]
    d: float  # torsional damping [N m s/rad]

    def __post_init__(self) -> None:
        require_positive("k", self.k)
        require_nonnegative("d", self.d)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"a": slot("d"), "b": slot("d")}

    def stiffness_bound(self, slot: SlotReader) -> float:
        return slot("k")

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dynamics":
            emit_two_port(g, "feed_twin.plant.coupling.spring_damper", (g.p("k"), g.p("d")))
