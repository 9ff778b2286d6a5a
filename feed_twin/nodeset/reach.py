"""Can the drive follow what the NC may command? Checked when a run's config is loaded.

For the twin axis at the NC's fastest rate v (rapid and feed limit, each checked) while it
accelerates at a_max:
- current: i_q = (J_total * a * 2 pi / lead + (F_friction(v) + |F_static|) * lead / (2 pi eta))
  / K_t must not exceed the controller's current limit (controller.drive.effort_limit).
  F_static is the load the drive holds at rest: the weight of every mass gravity pulls on
  (Gravity components: a machine's `vertical.m_kg`) less the counterbalance (ConstantForce,
  GasSpring), at its largest over the axis's travel; moving against it is the worst case;
- voltage (a PMSM on a DC bus): the stator voltage in steady state of the dq model,
  u_q = R_s i_q + omega_e psi_pm and u_d = -omega_e L_q i_q with omega_e = p * 2 pi v / lead,
  must stay within the inverter's linear range voltage_margin * u_dc / sqrt(3) (space-vector
  modulation); otherwise the current loop saturates, the motor cannot reach v and the following
  error grows without bound;
- speed: v must not exceed the drive's speed limit (ros.protection.speed_limit_m_s).
An unreachable limit is a ConfigError naming the NC field, what the drive needs, what it has
and the largest rate it reaches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

from feed_twin.core.config import ConfigError
from feed_twin.plant.ball_screw import BallScrew
from feed_twin.plant.component import Component
from feed_twin.plant.dc_bus import DcBus
from feed_twin.plant.external_force import ConstantForce
from feed_twin.plant.gas_spring import GasSpring
from feed_twin.plant.gravity import Gravity
from feed_twin.plant.guide_friction import GuideFriction
from feed_twin.plant.pmsm import Pmsm

C = TypeVar("C", bound=Component)


@dataclass(frozen=True, kw_only=True)
class DriveCapability:
    """What the drive of an axis can give, from its plant and controller sections."""

    lead_m: float  # [m/rev]
    efficiency: float  # [-] screw efficiency
    J_total_kg_m2: float  # [kg m^2] at the motor
    K_t: float  # [N m/A]
    current_limit_A: float  # [A]
    F_c_N: float  # [N] larger Coulomb friction of the guides
    F_v_N_s_m: float  # [N s/m] larger viscous friction of the guides
    F_static_N: float = 0.0  # [N] largest |weight - counterbalance| over the travel
    # a PMSM on a DC bus (None: no voltage limit is checked, e.g. an ideal force source)
    R_s: float | None = None  # [ohm]
    L_q: float | None = None  # [H]
    psi_pm: float | None = None  # [V s]
    pole_pairs: int | None = None
    u_max_V: float | None = None  # [V] largest stator voltage amplitude

    def current_at(self, v: float, a: float) -> float:
        """i_q [A] to move at v [m/s] while accelerating at a [m/s^2]."""
        ratio = 2.0 * math.pi / self.lead_m  # [rad/m]
        friction = (self.F_c_N + self.F_v_N_s_m * v + self.F_static_N) / (ratio * self.efficiency)
        return (self.J_total_kg_m2 * a * ratio + friction) / self.K_t

    def voltage_at(self, v: float, a: float) -> float:
        """Stator voltage amplitude [V] at v [m/s] while accelerating at a (NaN: not a PMSM)."""
        R_s, L_q, psi_pm, p = self.R_s, self.L_q, self.psi_pm, self.pole_pairs
        if self.u_max_V is None or R_s is None or L_q is None or psi_pm is None or p is None:
            return math.nan
        omega_e = p * 2.0 * math.pi * v / self.lead_m
        i_q = self.current_at(v, a)
        return math.hypot(R_s * i_q + omega_e * psi_pm, omega_e * L_q * i_q)

    def reachable_speed(self, a: float) -> float:
        """The largest v [m/s] whose voltage fits (bisection; the voltage grows with v)."""
        u_max = self.u_max_V
        if u_max is None:  # no voltage limit
            return math.inf
        low, high = 0.0, 1.0
        while self.voltage_at(high, a) < u_max and high < 1e3:
            high *= 2.0
        for _ in range(60):
            mid = 0.5 * (low + high)
            low, high = (mid, high) if self.voltage_at(mid, a) <= u_max else (low, mid)
        return low


def _first(components: list[Component], kind: type[C]) -> C | None:
    return next((c for c in components if isinstance(c, kind)), None)


def static_load(components: list[Component], travel_m: tuple[float, float]) -> float:
    """The largest |net static force| [N] on the axis over its travel: every Gravity's weight
    against the constant forces and gas springs pushing on it (linear in s: the ends bound
    it)."""
    worst = 0.0
    for s in travel_m:
        force = 0.0  # into the flange
        for c in components:
            if isinstance(c, Gravity):
                force -= c.slots()["weight"]
            elif isinstance(c, ConstantForce):
                force += c.f_0
            elif isinstance(c, GasSpring):
                force += c.f_0 - c.k * (s - c.s_0)
        worst = max(worst, abs(force))
    return worst


def capability(axis, travel_m: tuple[float, float] = (0.0, 0.0)) -> DriveCapability | None:
    """The drive capability of a feed_twin.sim.config.AxisConfig (None: no controller or no
    ball screw: nothing to check against); `travel_m` [m]: the slide's range, where a gas
    spring's force is judged."""
    controller = axis.controller
    if controller is None:
        return None
    components = list(axis.plant.components.values())
    screw = _first(components, BallScrew)
    guides = _first(components, GuideFriction)
    if screw is None:
        return None
    drive = controller.drive
    fields = {}
    motor, bus = _first(components, Pmsm), _first(components, DcBus)
    if motor is not None and bus is not None:
        current = controller.current
        margin = current.voltage_margin if current is not None else 1.0
        fields = {
            "R_s": motor.R_s,
            "L_q": motor.L_q,
            "psi_pm": motor.psi_pm,
            "pole_pairs": int(motor.p),
            "u_max_V": margin * bus.u_0 / math.sqrt(3.0),
        }
    return DriveCapability(
        lead_m=screw.lead,
        efficiency=screw.efficiency,
        J_total_kg_m2=drive.J_total_kg_m2,
        K_t=drive.K_t,
        current_limit_A=drive.effort_limit,
        F_c_N=0.0 if guides is None else max(guides.F_c_pos, guides.F_c_neg),
        F_v_N_s_m=0.0 if guides is None else max(guides.F_v_pos, guides.F_v_neg),
        F_static_N=static_load(components, travel_m),
        **fields,
    )


def check_reachable(axis, nc, speed_limit_m_s: float | None, *, source: str) -> None:
    """Raise ConfigError when the drive of the twin axis cannot reach the NC's limits."""
    spec = next(a for a in nc.axes if a.name == nc.twin_axis)
    cap = capability(axis, (spec.travel_min_m, spec.travel_max_m))
    if cap is None:
        return
    a = spec.a_max_m_s2
    for name in ("rapid_m_s", "v_max_m_s"):
        v = getattr(spec, name)
        field = f"{source}: nc.axes[{spec.name}].{name} = {v!r}"
        if speed_limit_m_s is not None and v > speed_limit_m_s:
            raise ConfigError(
                f"{field}: above the drive's speed limit ros.protection.speed_limit_m_s = "
                f"{speed_limit_m_s!r} by {100.0 * (v / speed_limit_m_s - 1.0):.1f} %"
            )
        i_q = cap.current_at(v, a)
        if i_q > cap.current_limit_A:
            raise ConfigError(
                f"{field}: accelerating at a_max_m_s2 = {a!r} there needs {i_q:.1f} A"
                f"{_static_words(cap)}, above "
                f"controller.drive.effort_limit = {cap.current_limit_A!r} A by "
                f"{100.0 * (i_q / cap.current_limit_A - 1.0):.1f} %"
            )
        u = cap.voltage_at(v, a)
        if cap.u_max_V is not None and u > cap.u_max_V:
            raise ConfigError(
                f"{field}: the motor needs {u:.0f} V there (back-EMF and R_s i_q at a_max_m_s2 "
                f"= {a!r}), the inverter gives {cap.u_max_V:.0f} V (controller.current."
                f"voltage_margin x bus u_0 / sqrt 3): short by "
                f"{100.0 * (u / cap.u_max_V - 1.0):.1f} %; the drive reaches "
                f"{cap.reachable_speed(a):.3f} m/s at most"
            )


def _static_words(cap: DriveCapability) -> str:
    if cap.F_static_N == 0.0:
        return ""
    return f" (holding a static load of {cap.F_static_N:.0f} N: weight less counterbalance)"
