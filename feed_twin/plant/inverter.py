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

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.smooth import smooth_sign, smooth_sign_array
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, Quantity, SlotSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Signature,
    Weights,
    first_of,
    make_edit,
    motor_angle,
)

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


# [A] sign-smoothing currents searched for the dead time (PWM current ripple of small to large
# drives): below i_reg the inverter's voltage error grows linearly with the phase current
DEAD_TIME_CURRENT_SCALES_A = (0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0)


def dead_time_voltage(
    i_q_A: FloatArray, theta_e_rad: FloatArray, i_reg_A: float
) -> dict[str, FloatArray]:
    """d/q components of the three phases' smooth sgn(i_x / i_reg) at i_d = 0.

    A two-level inverter leg with interlock time T_d at PWM period T_s loses about
    u_dc T_d / T_s of its pole voltage while its phase current i_x flows out of the leg and
    gains it while the current flows in: an error -u_dc (T_d/T_s) sgn(i_x) per phase (the
    device drop u_f sgn(i_x) has the same shape and is not told apart from it). The Park
    transform of these three square waves at i_d ~ 0 is a voltage along the current vector of
    mean (4/pi) u_dc T_d/T_s sgn(i_q) with a ripple at six times the electrical frequency. A
    drive's PI current loop supplies the missing voltage within a few current-loop periods, so
    the current keeps only a small trace; the voltage the controller commands carries the whole
    error. Amplitude-invariant Clarke and Park, as the drive's controller uses them.
    """
    i_alpha = -np.sin(theta_e_rad) * i_q_A
    i_beta = np.cos(theta_e_rad) * i_q_A
    half = 0.5 * math.sqrt(3.0) * i_beta
    phases = (i_alpha, -0.5 * i_alpha + half, -0.5 * i_alpha - half)
    s_a, s_b, s_c = (smooth_sign_array(x, i_reg_A) for x in phases)
    s_alpha = (2.0 / 3.0) * (s_a - 0.5 * (s_b + s_c))
    s_beta = (s_b - s_c) / math.sqrt(3.0)
    return {
        "d": np.cos(theta_e_rad) * s_alpha + np.sin(theta_e_rad) * s_beta,
        "q": -np.sin(theta_e_rad) * s_alpha + np.cos(theta_e_rad) * s_beta,
    }


def _dead_time_choices(m: Motion) -> list[tuple[str, Signature]]:
    # the weight of the q part computed from the measured q-current at the electrical angle
    # p 2 pi x / lead is u_dc Delta T_d / T_s, the extra volts the controller must command;
    # where the motion knows the current loop's answer to a voltage error (a twin without an
    # Inverter), the current dip it leaves after each reversal, ranked on the effort
    def make(i_reg: float) -> Signature:
        def signature(mm: Motion) -> dict[str, FloatArray]:
            assert mm.current_q_A is not None and mm.pole_pairs is not None
            theta_e = mm.pole_pairs * motor_angle(mm)
            volts = dead_time_voltage(mm.current_q_A, theta_e, i_reg)["q"]
            answer = mm.current_answer
            return {"sgn_i_q": volts if answer is None else answer(volts)}

        return signature

    return [(f"i_reg = {i:g} A", make(i)) for i in DEAD_TIME_CURRENT_SCALES_A]


def _dead_time_edit(doc: Document, cand: Weights) -> Edit:
    """The Inverter's dead time t_dead is fitted (the controller's compensation stays as it is).

    Averaged inverter: the fitted engine slot is dead_fraction = t_dead f_pwm (stored as t_dead).
    Ranked on the q-voltage residual, the weight c of the signature is the extra voltage the
    controller must command, u_dc Delta t_dead f_pwm, so the guess is dead_fraction + c / u_dc;
    ranked on the effort (no voltage recorded) the weight is in amperes and says nothing about
    the size, so the fit starts at the nominal value. The device drop u_f stays nominal: it has
    the same sgn(i) shape and cannot be told apart from the dead time.
    """
    name = first_of(doc, Inverter.TYPE, "whose dead time could be fitted")
    params = doc.component(name)["params"]
    f_pwm = float(params["f_pwm"])
    switching = params.get("model") == "switching"
    slot = f"{name}.t_dead" if switching else f"{name}.dead_fraction"
    per_fraction = 1.0 / f_pwm if switching else 1.0  # slot units per unit of dead fraction
    fraction = doc.get(f"{name}.t_dead") * f_pwm
    buses = doc.of_type("DcBus")
    u_dc = doc.get(f"{buses[0]}.u_0") if buses else None
    if cand.residual_domain == "voltage" and u_dc:
        fraction = fraction + cand.coefficients.get("sgn_i_q", 0.0) / u_dc
    # the Inverter accepts t_dead up to 10 % of the PWM period
    fraction = min(max(fraction, 1e-4), 0.09)
    doc = doc.set(slot, fraction * per_fraction)
    own = [
        FreeParameter(
            name=slot,
            initial=fraction * per_fraction,
            scale=fraction * per_fraction,
            lower=0.0,
            upper=0.099 * per_fraction,
        )
    ]
    to_seconds = 1.0 if switching else 1.0 / f_pwm
    return make_edit(doc, own, {"t_dead_s": lambda v: v[slot] * to_seconds}, interacts=False)


def _dead_time_truth(doc: Document, p: Mapping[str, float]) -> Document:
    # the controller's dead-time compensation stays tuned for the nominal dead time
    name = first_of(doc, Inverter.TYPE, "whose dead time could be fitted")
    return doc.set(f"{name}.t_dead", p["t_dead_s"])


def _set_dead_fraction(params: dict[str, Any], value: float) -> None:
    params["t_dead"] = float(value) / float(params["f_pwm"])


@dataclass(frozen=True, kw_only=True)
class Inverter(Component):
    TYPE = "Inverter"
    PORTS = {"dc": "dc", "ac": "ac3"}
    COMPUTED_SLOTS = {"dead_fraction": SlotSpec(unit="1", low=0.0, high=1.0)}  # t_dead * f_pwm
    EFFECTS = (
        Effect(
            name="dead_time",
            domain="voltage",
            fallback="effort",
            words="a voltage error that flips with the sign of the phase currents and ripples "
            "six times per electrical revolution: the inverter's dead time eats part of every "
            "phase voltage, and the current controller must command the missing volts",
            parameters="t_dead",
            needs=("current_q_A", "lead_m", "pole_pairs"),
            choices=_dead_time_choices,
            edit=_dead_time_edit,
            truth=_dead_time_truth,
        ),
    )
    # the averaged model's engine slot dead_fraction = t_dead f_pwm (the duty the dead time
    # removes), stored as t_dead
    QUANTITIES = {
        "dead_fraction": Quantity(
            stored_as=("t_dead", "f_pwm"),
            read=lambda params: float(params["t_dead"]) * float(params["f_pwm"]),
            write=_set_dead_fraction,
        )
    }

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

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "dc_current":
            enabled = g.drive("OUT_ENABLED")
            terms: list[str] = []
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
            loss: list[str] = []
            for x in PHASES:
                u, i = g.el("ac", f"u_{x}"), g.el("ac", f"i_{x}")
                duty, sgn = g.local(f"d_{x}"), g.local(f"sgn_{x}")
                g.line(f"{u} = {duty} * {u_dc} - {g.p('u_f')} * {sgn}")
                g.aux(f"u_{x}", u)
                loss.append(f"({u_dc} * {duty} - {u}) * {i}")
            g.power("loss", "conduction", " + ".join(loss))
