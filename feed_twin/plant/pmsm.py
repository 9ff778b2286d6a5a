"""Permanent-magnet synchronous machine in the rotor (d, q) frame, with iron loss and cogging.

Electrical (amplitude-invariant transforms, electrical speed omega_e = p*omega, angle p*phi):
    psi_d = L_d*i_d + psi_pm,  psi_q = L_q*i_q,  e_d = -omega_e*psi_q,  e_q = omega_e*psi_d,
    L_d di_d/dt = u_d - R_s*i_d - e_d,   L_q di_q/dt = u_q - R_s*i_q - e_q,
where i_d, i_q are the terminal currents (the states). The iron-loss resistance R_fe sits across
the induced voltage e: it draws i_fe = e/R_fe, and only the remainder i_m = i - i_fe makes torque:
    tau_e = 1.5 * p * (psi_d*i_m,q - psi_q*i_m,d)  (= 1.5*p*(psi_pm*i_q + (L_d - L_q)*i_d*i_q)
                                                     when R_fe is absent).
Power balance, exact: 1.5*(u_d*i_d + u_q*i_q) = copper 1.5*R_s*|i|^2 + iron 1.5*|e|^2/R_fe
+ d/dt(0.75*(L_d*i_d^2 + L_q*i_q^2)) + tau_e*omega.
Mechanical: rotor inertia J on the flange; bearing friction tau_f = T_c*sgn(omega/omega_reg) +
b*omega against the motion; cogging torque sum_k A_k*sin(n_k*phi + phase_k) (n_k per mechanical
revolution), the gradient of the potential -sum_k A_k/n_k*cos(n_k*phi + phase_k).
The stator windings are star-connected with an isolated neutral, so the zero-sequence part of the
pole voltages drops out.
Inverter off (OUT_ENABLED = 0): with all switches open and the line back-EMF below the bus
voltage the freewheeling diodes block as soon as the currents reach zero, within tens of
microseconds; an explicit step cannot follow that commutation (the regularised diode model is a
stiff resistor near zero current), so the currents decay as di/dt = -i/T_open instead, T_open
a few steps. Not modelled: generator braking through the diodes when the line back-EMF exceeds
the bus (motor speeds near the voltage limit), and the energy balance while the drive is off.
Ports: `ac` (ac3: pole voltages [V] in, phase currents [A] out), `flange` (rotational: phi [rad],
omega [rad/s], tau [N m] into the flange).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.cogging_torque import CoggingTorque
from feed_twin.plant.component import (
    Component,
    Emitter,
    InertiaSpec,
    Quantity,
    SlotReader,
    SlotSpec,
    StateSpec,
)
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Report,
    Signature,
    Weights,
    first_of,
    make_edit,
    motor_angle,
)

COGGING_ORDERS = tuple(range(1, 25))  # harmonics per motor revolution searched for cogging
COGGING_SLOT = re.compile(r"^cog(\d+)_(order|amplitude|phase)$")  # the slots of a harmonic

SQRT3 = math.sqrt(3.0)


@njit(error_model="numpy", forceinline=True)
def phase_currents(i_d: float, i_q: float, c: float, s: float) -> tuple[float, float, float]:
    """(i_a, i_b, i_c) from the rotor-frame currents; (c, s) = (cos, sin) of theta_e."""
    i_alpha = c * i_d - s * i_q
    i_beta = s * i_d + c * i_q
    return (
        i_alpha,
        -0.5 * i_alpha + 0.5 * SQRT3 * i_beta,
        -0.5 * i_alpha - 0.5 * SQRT3 * i_beta,
    )


@njit(error_model="numpy", forceinline=True)
def pmsm_dq(
    u_a: float,
    u_b: float,
    u_c: float,
    c: float,
    s: float,
    i_d: float,
    i_q: float,
    omega: float,
    R_s: float,
    L_d: float,
    L_q: float,
    psi_pm: float,
    p: float,
    G_fe: float,
    enabled: float,
    T_open: float,
) -> tuple[float, float, float, float, float, float, float]:
    """(di_d/dt, di_q/dt, tau_e, copper loss, iron loss, u_d, u_q) of the dq machine."""
    u_alpha = (2.0 / 3.0) * (u_a - 0.5 * u_b - 0.5 * u_c)
    u_beta = (u_b - u_c) * (1.0 / SQRT3)
    u_d = c * u_alpha + s * u_beta
    u_q = -s * u_alpha + c * u_beta
    omega_e = p * omega
    psi_d = L_d * i_d + psi_pm
    psi_q = L_q * i_q
    e_d = -omega_e * psi_q
    e_q = omega_e * psi_d
    i_md = i_d - G_fe * e_d
    i_mq = i_q - G_fe * e_q
    tau_e = 1.5 * p * (psi_d * i_mq - psi_q * i_md)
    if enabled < 0.5:
        di_d = -i_d * (1.0 / T_open)
        di_q = -i_q * (1.0 / T_open)
    else:
        # reciprocals of parameters: the compiled loop hoists them, divisions would stay
        di_d = (u_d - R_s * i_d - e_d) * (1.0 / L_d)
        di_q = (u_q - R_s * i_q - e_q) * (1.0 / L_q)
    return (
        di_d,
        di_q,
        tau_e,
        1.5 * R_s * (i_d * i_d + i_q * i_q),
        1.5 * G_fe * (e_d * e_d + e_q * e_q),
        u_d,
        u_q,
    )


@njit(error_model="numpy", forceinline=True)
def cogging(phi: float, order: float, amplitude: float, phase: float) -> tuple[float, float]:
    """(torque [N m], potential [J]) of one cogging harmonic."""
    arg = order * phi + phase
    return amplitude * math.sin(arg), amplitude / order * math.cos(arg)


@dataclass(frozen=True, kw_only=True)
class CoggingHarmonic:
    order: int  # periods per mechanical revolution (e.g. the lcm of slots and poles)
    amplitude: float  # torque amplitude [N m]
    phase: float  # phase [rad]

    def __post_init__(self) -> None:
        if self.order < 1:
            raise ValueError(f"order = {self.order!r}: must be >= 1")
        require_nonnegative("amplitude", self.amplitude)


def with_cogging(doc: Document, order: int, amplitude: float, phase: float) -> tuple[Document, str]:
    """The document with a cogging harmonic on its (first) Pmsm, or, in a model without one, a
    CoggingTorque on the flange of its rotational EffortSource (the rotor of a drive behind its
    current loop); (document, slot prefix)."""
    if not doc.of_type(Pmsm.TYPE):
        source = rotor_source(doc)
        params = {"order": int(order), "amplitude": float(amplitude), "phase": float(phase)}
        doc, name = doc.with_component(
            "cogging", CoggingTorque.TYPE, params, [["{name}.flange", f"{source}.flange"]]
        )
        return doc, f"{name}."
    motor = first_of(doc, Pmsm.TYPE, "to carry cogging")
    harmonics = list(doc.component(motor)["params"].get("cogging", []))
    harmonics.append({"order": int(order), "amplitude": float(amplitude), "phase": float(phase)})
    return doc.set_raw(motor, "cogging", harmonics), f"{motor}.cog{len(harmonics) - 1}_"


def rotor_source(doc: Document) -> str:
    """The model's EffortSource that drives a rotor flange, or a LookupError."""
    for name in doc.of_type("EffortSource"):
        if doc.component(name).get("params", {}).get("domain") == "rotational":
            return name
    raise LookupError(
        "the model has no Pmsm, nor an EffortSource on a rotor flange, to carry cogging"
    )


def _torque_per_effort(doc: Document, cand: Weights) -> float:
    """[N m per unit of the effort residual] the motor's K_t (a current), else, on an effort
    source's rotor, the weight's force at the table back through the screw (a starting value:
    the amplitude is fitted)."""
    if doc.of_type(Pmsm.TYPE):
        return torque_constant(doc)
    screw = first_of(doc, "BallScrew", "whose lead turns the table's force into torque")
    return cand.force_per_unit * doc.get(f"{screw}.lead") / (2.0 * math.pi)


def torque_constant(doc: Document) -> float:
    """K_t [N m/A] of the document's first Pmsm."""
    return doc.get(f"{first_of(doc, Pmsm.TYPE, 'to carry cogging')}.K_t")


def _cogging_edit(doc: Document, cand: Weights) -> Edit:
    """A cogging harmonic of the order the signature found (cogging_edit)."""
    return cogging_edit(doc, cand, int(cand.variant.split()[1]) if cand.variant else 6)


def cogging_edit(doc: Document, cand: Weights, order: int) -> Edit:
    """A torque harmonic of `order` per motor revolution; amplitude and phase are fitted.

    The drive must supply -tau_cog = -A sin(k phi + psi), so the current residual is
    -(A/K_t) sin(k phi + psi): the weights (s, c) of (sin, cos) give A = K_t sqrt(s^2 + c^2)
    and psi = atan2(-c, -s).
    """
    s_w, c_w = cand.coefficients.get("sin", 0.0), cand.coefficients.get("cos", 0.0)
    amplitude = max(_torque_per_effort(doc, cand) * math.hypot(s_w, c_w), 1e-4)
    phase = math.atan2(-c_w, -s_w)
    doc, prefix = with_cogging(doc, order, amplitude, phase)
    own = [
        FreeParameter(name=f"{prefix}amplitude", initial=amplitude, scale=amplitude, lower=0.0),
        FreeParameter(name=f"{prefix}phase", initial=phase, scale=1.0),
    ]
    report: Report = {
        "order": lambda v: float(order),
        "amplitude_Nm": lambda v: v[f"{prefix}amplitude"],
        "phase_rad": lambda v: v[f"{prefix}phase"],
    }
    return make_edit(doc, own, report, interacts=False)


def _cogging_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return with_cogging(doc, int(p["order"]), p["amplitude_Nm"], p["phase_rad"])[0]


def _cogging_choices(m: Motion) -> list[tuple[str, Signature]]:
    def make(k: int) -> Signature:
        return lambda mm: {
            "sin": np.sin(k * motor_angle(mm)),
            "cos": np.cos(k * motor_angle(mm)),
        }

    # once per electrical revolution (order = pole pairs) is current_offset's signature, once
    # per revolution a lead error's or an eccentricity's (on a direct-drive screw): a cogging
    # torque repeats lcm(slots, 2 p) >= 2 times per revolution, never once and never p times
    # (the truth machine's lead error was named a cogging of order 1 when its twin could carry
    # one)
    orders = [k for k in COGGING_ORDERS if k > 1 and k != m.pole_pairs]
    return [(f"order {k} per motor revolution", make(k)) for k in orders]


def _harmonic(n: int, key: str) -> Quantity:
    """Slot `cog<n>_<key>`: a field of the n-th entry of the YAML's cogging list."""

    def write(params: dict[str, Any], value: float) -> None:
        params["cogging"][n][key] = int(round(value)) if key == "order" else float(value)

    return Quantity(
        stored_as=("cogging",),
        read=lambda params: float(params.get("cogging", [])[n][key]),
        write=write,
        exists=lambda params: n < len(params.get("cogging", [])),
    )


def _set_torque_constant(params: dict[str, Any], value: float) -> None:
    params["psi_pm"] = float(value) / (1.5 * float(params["p"]))


@dataclass(frozen=True, kw_only=True)
class Pmsm(Component):
    TYPE = "Pmsm"
    PORTS = {"ac": "ac3", "flange": "rotational"}
    COMPUTED_SLOTS = {"G_fe": SlotSpec(unit="S", low=0.0)}  # 1 / R_fe, 0 without iron loss
    _COGGING_SLOTS = {
        "order": SlotSpec(unit="1", low=1.0, integer=True),
        "amplitude": SlotSpec(unit="N m", low=0.0),
        "phase": SlotSpec(unit="rad"),
    }

    @classmethod
    def computed_slot(cls, name: str) -> SlotSpec | None:
        harmonic = re.fullmatch(r"cog\d+_(\w+)", name)
        if harmonic is None:
            return super().computed_slot(name)
        return cls._COGGING_SLOTS.get(harmonic.group(1))

    EFFECTS = (
        Effect(
            name="cogging_torque",
            domain="effort",
            words="a force ripple that repeats a fixed number of times per motor revolution",
            parameters="cogging",
            needs=("lead_m",),
            choices=_cogging_choices,
            edit=_cogging_edit,
            truth=_cogging_truth,
        ),
    )
    # K_t = 1.5 p psi_pm [N m/A] (amplitude-invariant dq)
    QUANTITIES = {
        "K_t": Quantity(
            stored_as=("p", "psi_pm"),
            read=lambda params: 1.5 * float(params["p"]) * float(params["psi_pm"]),
            write=_set_torque_constant,
        )
    }

    @classmethod
    def quantity(cls, name: str) -> Quantity | None:
        harmonic = COGGING_SLOT.match(name)
        if harmonic is not None:
            return _harmonic(int(harmonic.group(1)), harmonic.group(2))
        return super().quantity(name)

    # phi and omega: the rotor's coordinate, which carries the motor's name as its first body
    STATE_OUTPUTS = {
        "motor_angle": "phi",
        "motor_velocity": "omega",
        "i_d": "i_d",
        "i_q": "i_q",
        "u_d": "u_d",
        "u_q": "u_q",
        "torque_em": "tau_e",
    }

    R_s: float  # stator resistance per phase [ohm]
    L_d: float  # d-axis inductance [H]
    L_q: float  # q-axis inductance [H]
    psi_pm: float  # permanent-magnet flux linkage, amplitude [V s]
    p: int  # pole pairs [1]
    R_fe: float | None  # iron-loss resistance [ohm]; null for no iron loss
    J: float  # rotor inertia [kg m^2]
    T_c: float  # bearing/seal Coulomb friction torque [N m]
    b: float  # bearing viscous friction [N m s/rad]
    omega_reg: float  # regularisation speed of the friction sign [rad/s]
    cogging: tuple[CoggingHarmonic, ...] = ()
    i_max: float  # current magnitude above which the state counts as a runaway [A]
    T_open: float  # decay time of the currents while the inverter is off [s], >= 2.5 x step

    def __post_init__(self) -> None:
        for name in ("R_s", "L_d", "L_q", "psi_pm", "J", "omega_reg", "i_max", "T_open"):
            require_positive(name, getattr(self, name))
        if self.p < 1:
            raise ValueError(f"p = {self.p!r}: must be >= 1")
        if self.R_fe is not None:
            require_positive("R_fe", self.R_fe)
        require_nonnegative("T_c", self.T_c)
        require_nonnegative("b", self.b)

    def slots(self) -> dict[str, float]:
        values = {
            "R_s": self.R_s,
            "L_d": self.L_d,
            "L_q": self.L_q,
            "psi_pm": self.psi_pm,
            "p": float(self.p),
            "G_fe": 0.0 if self.R_fe is None else 1.0 / self.R_fe,
            "J": self.J,
            "T_c": self.T_c,
            "b": self.b,
            "omega_reg": self.omega_reg,
            "T_open": self.T_open,
        }
        for n, h in enumerate(self.cogging):
            values[f"cog{n}_order"] = float(h.order)
            values[f"cog{n}_amplitude"] = h.amplitude
            values[f"cog{n}_phase"] = h.phase
        return values

    def states(self) -> tuple[StateSpec, ...]:
        return (
            StateSpec(name="i_d", unit="A", limit=self.i_max),
            StateSpec(name="i_q", unit="A", limit=self.i_max),
        )

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return (InertiaSpec(port="flange", slot="J"),)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"flange": slot("T_c") / slot("omega_reg") + slot("b")}

    def emit(self, stage: str, g: Emitter) -> None:
        phi, omega = g.across("flange")
        c, s = g.local("cos"), g.local("sin")  # the pair g.angle declares, for later stages
        if stage == "currents":
            # the electrical angle, for both Park transforms of the call (the loop rotates its
            # pair from the tick's start instead of evaluating it anew: Emitter.angle)
            c, s = g.angle(f"{g.p('p')} * {phi}")
            g.call(
                (g.el("ac", "i_a"), g.el("ac", "i_b"), g.el("ac", "i_c")),
                "feed_twin.plant.pmsm.phase_currents",
                (g.x("i_d"), g.x("i_q"), c, s),
            )
        elif stage == "dynamics":
            di_d, di_q, tau_e, p_cu, p_fe, u_d, u_q = (
                g.local(n) for n in ("di_d", "di_q", "tau_e", "p_cu", "p_fe", "u_d", "u_q")
            )
            g.call(
                (di_d, di_q, tau_e, p_cu, p_fe, u_d, u_q),
                "feed_twin.plant.pmsm.pmsm_dq",
                (g.el("ac", "u_a"), g.el("ac", "u_b"), g.el("ac", "u_c"), c, s)
                + (g.x("i_d"), g.x("i_q"), omega)
                + tuple(g.p(n) for n in ("R_s", "L_d", "L_q", "psi_pm", "p", "G_fe"))
                + (g.drive("OUT_ENABLED"), g.p("T_open")),
            )
            g.d("i_d", di_d)
            g.d("i_q", di_q)
            tau_f = g.local("tau_f")
            g.call(
                (tau_f,),
                "feed_twin.plant.guide_friction.friction_force",
                (omega, g.p("T_c"), g.p("T_c"), g.p("b"), g.p("b"), "0.0", "1.0")
                + (g.p("omega_reg"),),
            )
            torque = [tau_e, f"-{tau_f}"]
            for n in range(len(self.cogging)):
                tau_cog, v_cog = g.local(f"tau_cog{n}"), g.local(f"v_cog{n}")
                g.call(
                    (tau_cog, v_cog),
                    "feed_twin.plant.pmsm.cogging",
                    (phi, g.p(f"cog{n}_order"), g.p(f"cog{n}_amplitude"), g.p(f"cog{n}_phase")),
                )
                torque.append(tau_cog)
                g.stored(f"cogging{n}", v_cog)
            g.apply("flange", " + ".join(torque))
            g.aux("tau_e", tau_e)
            g.aux("u_d", u_d)
            g.aux("u_q", u_q)
            g.aux("p_elec", f"1.5 * ({u_d} * {g.x('i_d')} + {u_q} * {g.x('i_q')})")
            g.aux("p_mech", f"{tau_e} * {omega}")
            for x in ("a", "b", "c"):
                g.aux(f"i_{x}", g.el("ac", f"i_{x}"))
            g.power("loss", "copper", p_cu)
            g.power("loss", "iron", p_fe)
            g.power("loss", "bearing", f"{tau_f} * {omega}")
            g.stored(
                "magnetic",
                f"0.75 * ({g.p('L_d')} * {g.x('i_d')} ** 2 + {g.p('L_q')} * {g.x('i_q')} ** 2)",
            )
