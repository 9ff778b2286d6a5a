"""Two-level three-phase voltage-source inverter, averaged or switching.

Each leg x in {a, b, c} sets a pole voltage (against the negative bus rail) from its switch state
and the sign of its phase current i_x (out of the leg, into the machine):
    u_x = d_eff,x * u_dc - u_f * sgn(i_x),   i_dc = sum_x d_eff,x * i_x,
where u_f is the conduction drop of the conducting IGBT or diode and sgn(i) is the smooth sign
of i / i_reg (feed_twin.core.smooth).
Averaged model (`model: averaged`): d_eff = d - t_dead * f_pwm * sgn(i): dead time removes
t_dead of high time per period when the current leaves the leg (the lower diode holds the pole
low until the delayed upper switch turns on) and adds it when the current enters.
Switching model (`model: switching`): d_eff is the instantaneous switch state 0 or 1; the engine
integrates piecewise between the exact edges of centre-aligned PWM (high on [(1-d)T/2, (1+d)T/2]
of each period T) and inserts the dead-time intervals, during which both switches are off and
d_eff = (1 - sgn(i))/2 (the freewheeling diode of the current's direction conducts).
A disabled drive (OUT_ENABLED = 0) opens all switches: every leg is a diode pair, d_eff =
(1 - sgn(i))/2, so currents decay into the bus. Power: u_dc*i_dc in, sum u_x*i_x out, the
difference sum u_f*sgn(i_x)*i_x >= 0 is the conduction loss.
Ports: `dc` (dc: u [V], i [A] drawn), `ac` (ac3: pole voltages u_a..u_c [V] set here, phase
currents i_a..i_c [A] set by the machine).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from numba import njit

from feed_twin.core.smooth import smooth_sign
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter

PHASES = ("a", "b", "c")
DUTY_SLOTS = ("OUT_DUTY_A", "OUT_DUTY_B", "OUT_DUTY_C")
BOTH_OFF = -1.0  # switch-state marker of a dead-time interval in the switching model


@njit(error_model="numpy", forceinline=True)
def leg_duty(
    command: float, i: float, dead_fraction: float, i_reg: float, enabled: float
) -> tuple[float, float]:
    """(effective duty or switch state, smooth sign of i) of one leg.

    command < 0 marks a dead-time interval of the switching model (both switches off).
    """
    sgn = smooth_sign(i, i_reg)
    if enabled < 0.5 or command < 0.0:
        return 0.5 * (1.0 - sgn), sgn
    return command - dead_fraction * sgn, sgn


@dataclass(frozen=True, kw_only=True)
class Inverter(Component):
    TYPE = "Inverter"
    PORTS = {"dc": "dc", "ac": "ac3"}

    model: Literal["averaged", "switching"]
    f_pwm: float  # switching frequency [Hz]
    t_dead: float  # interlock dead time [s]
    u_f: float  # conduction drop of an IGBT or diode [V]
    i_reg: float  # current scale of the smooth sign function [A]

    def __post_init__(self) -> None:
        require_positive("f_pwm", self.f_pwm)
        require_nonnegative("t_dead", self.t_dead)
        if self.t_dead * self.f_pwm >= 0.1:
            raise ValueError(f"t_dead = {self.t_dead!r}: must be < 10 % of the PWM period 1/f_pwm")
        require_nonnegative("u_f", self.u_f)
        require_positive("i_reg", self.i_reg)

    @property
    def switching(self) -> bool:
        return self.model == "switching"

    def slots(self) -> dict[str, float]:
        return {
            "f_pwm": self.f_pwm,
            "t_dead": self.t_dead,
            # the averaged model applies dead time as a duty error; the switching one as edges
            "dead_fraction": 0.0 if self.switching else self.t_dead * self.f_pwm,
            "u_f": self.u_f,
            "i_reg": self.i_reg,
        }

    def structure(self) -> tuple:
        return (self.model,)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dc_current":
            enabled = g.drive("OUT_ENABLED")
            terms = []
            for n, x in enumerate(PHASES):
                command = g.switch(n) if self.switching else g.drive(DUTY_SLOTS[n])
                duty, sgn = g.local(f"d_{x}"), g.local(f"sgn_{x}")
                i = g.el("ac", f"i_{x}")
                g.call(
                    (duty, sgn),
                    "feed_twin.plant.inverter.leg_duty",
                    (command, i, g.p("dead_fraction"), g.p("i_reg"), enabled),
                )
                terms.append(f"{duty} * {i}")
            g.line(f"{g.el('dc', 'i')} = {' + '.join(terms)}")
        elif stage == "voltages":
            u_dc = g.el("dc", "u")
            loss = []
            for x in PHASES:
                u, i = g.el("ac", f"u_{x}"), g.el("ac", f"i_{x}")
                duty, sgn = g.local(f"d_{x}"), g.local(f"sgn_{x}")
                g.line(f"{u} = {duty} * {u_dc} - {g.p('u_f')} * {sgn}")
                g.aux(f"u_{x}", u)
                loss.append(f"({u_dc} * {duty} - {u}) * {i}")
            g.power("loss", "conduction", " + ".join(loss))
