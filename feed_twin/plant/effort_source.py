"""Ideal force or torque source behind a first-order current loop.

For drives where only the force command is known (the EMPS bench: force = gtau * vir): the
commanded effort f_cmd = gain * effort_cmd (0 while the drive is disabled) is reached through
    T_lag * df/dt = f_cmd - f     (T_lag > 0; the closed current loop as a first-order lag),
or f = f_cmd at once when T_lag = 0. The source delivers f*v into the axis.
A rotational source whose drive's current loop is given (R_s, L_s, Kp_i, Ti_i, emf_ratio, u_max:
all or none, T_lag = 0) takes its command as the current setpoint [A] of that loop, a PI on the
motor's windings with the back-EMF of the flange's speed (plant.current_loop), and delivers
gain times the loop's current.
Port: `flange` (rotational [rad, rad/s, N m] or translational [m, m/s, N], set by `domain`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, PortKind, SlotReader, StateSpec
from feed_twin.plant.current_loop import fastest_rate
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Report,
    Weights,
    make_edit,
    slot_reader,
    symmetric,
)

# where a model keeps the constant that turns force into the recorded effort, first found
# first: the drive gain of an EffortSource, else the motor's flux (K_t = 1.5 p psi_pm) or the
# DC motor's k; each divides the recorded effort (the current the drive needs for a force)
_EFFORT_CONSTANTS = (("EffortSource", "gain"), ("Pmsm", "psi_pm"), ("DcMotor", "k"))
# the fields that give an EffortSource its drive's current loop (plant.current_loop), in the
# order its law takes them
CURRENT_LOOP_FIELDS = ("R_s", "L_s", "Kp_i", "Ti_i", "emf_ratio", "u_max")
LOOP_VOLTAGE_LIMITS = 100.0  # |z| beyond this many voltage limits is a runaway


def _gain_slot(doc: Document) -> str:
    for kind, field_name in _EFFORT_CONSTANTS:
        found = doc.of_type(kind)
        if found:
            return f"{found[0]}.{field_name}"
    raise LookupError("the model has no EffortSource, Pmsm or DcMotor whose constant to fit")


def _gain_edit(doc: Document, cand: Weights) -> Edit:
    g = _gain_slot(doc)
    doc = symmetric(doc)
    value = doc.get(g)
    # measured effort = K_nom/K_true * needed effort: weight c = K_nom/K_true - 1
    guess = value / (1.0 + cand.coefficients.get("effort", 0.0))
    doc = doc.set(g, guess)
    own = [FreeParameter(name=g, initial=guess, scale=abs(value))]
    # the constant scales every force of the model at once: fitted together with the mass and
    # friction it would be degenerate, so it is fitted alone (the report says the correlation)
    report: Report = {"gain": slot_reader(g), "effort_scale": lambda v: value / v[g]}
    return make_edit(doc, own, report, interacts=False)


def _gain_truth(doc: Document, p: Mapping[str, float]) -> Document:
    g = _gain_slot(doc)
    if "effort_scale" in p:
        return doc.set(g, doc.get(g) / p["effort_scale"])
    return doc.set(g, p["gain"])


def _effort_signature(m: Motion) -> dict[str, FloatArray]:
    assert m.effort_sim is not None  # the effect needs effort_sim
    return {"effort": m.effort_sim}


@dataclass(frozen=True, kw_only=True)
class EffortSource(Component):
    TYPE = "EffortSource"
    PORTS = {}
    EFFECTS = (
        Effect(
            name="torque_constant_error",
            domain="effort",
            words="the whole effort is off by a fixed ratio: the torque (force) constant of the "
            "drive differs from the data sheet, or the record's current has another scale (the "
            "first unknown of a foreign machine)",
            parameters="gain (a motor model: Pmsm.psi_pm or DcMotor.k)",
            needs=("effort_sim",),
            signature=_effort_signature,
            edit=_gain_edit,
            truth=_gain_truth,
        ),
    )

    domain: Literal["rotational", "translational"]
    gain: float  # effort per drive input unit [N/V, N m/V or N/A ...]
    T_lag: float  # time constant of the current loop [s], 0 for an instantaneous source
    f_max: float  # effort magnitude counted as a runaway [N or N m]
    # the drive's current loop (plant.current_loop), all given or none (an ideal source)
    R_s: float | None = None  # winding resistance [ohm]
    L_s: float | None = None  # winding inductance [H]
    Kp_i: float | None = None  # current PI gain [V/A]
    Ti_i: float | None = None  # current PI integral time [s]
    emf_ratio: float | None = None  # back-EMF constant over the torque constant [1]
    u_max: float | None = None  # the loop's voltage limit [V]

    def __post_init__(self) -> None:
        require_finite("gain", self.gain)
        require_nonnegative("T_lag", self.T_lag)
        require_positive("f_max", self.f_max)
        given = {n: getattr(self, n) for n in CURRENT_LOOP_FIELDS}
        if any(v is not None for v in given.values()):
            missing = [n for n, v in given.items() if v is None]
            if missing:
                raise ValueError(
                    f"{', '.join(missing)} = None: the current loop needs all of "
                    f"{', '.join(CURRENT_LOOP_FIELDS)}"
                )
            for name, value in given.items():
                require_positive(name, value)
            if self.T_lag != 0.0:
                raise ValueError(
                    f"T_lag = {self.T_lag!r}: must be 0 with a current loop (its own lag)"
                )
            if self.gain == 0.0:
                raise ValueError("gain = 0.0: a current loop's torque constant must not be 0")
            if self.domain != "rotational":
                raise ValueError(
                    f"domain = {self.domain!r}: a current loop drives a motor (rotational)"
                )

    @property
    def has_current_loop(self) -> bool:
        return self.R_s is not None

    def state_rate(self, slot: SlotReader) -> float:
        """The current loop's fastest pole [1/s]; 1 / T_lag for a first-order lag; 0 for an
        instantaneous source."""
        if not self.has_current_loop:
            if self.T_lag <= 0.0:
                return 0.0
            t_lag = slot("T_lag")
            return 1.0 / t_lag if t_lag > 0.0 else float("inf")
        return fastest_rate(slot("R_s"), slot("L_s"), slot("Kp_i"), slot("Ti_i"))

    def ports(self) -> dict[str, PortKind]:
        return {"flange": self.domain}

    def states(self) -> tuple[StateSpec, ...]:
        unit = "N m" if self.domain == "rotational" else "N"
        if self.has_current_loop:
            return (
                StateSpec(name="i", unit="A", limit=self.f_max / abs(self.gain)),
                StateSpec(name="z", unit="V", limit=LOOP_VOLTAGE_LIMITS * self._u_max()),
            )
        if self.T_lag > 0.0:
            return (StateSpec(name="effort", unit=unit, limit=self.f_max),)
        return ()

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, v = g.across("flange")
        if self.has_current_loop:
            self._emit_loop(g, v)
            return
        command = f"{g.p('gain')} * {g.drive('OUT_EFFORT_CMD')} * {g.drive('OUT_ENABLED')}"
        if self.T_lag > 0.0:
            f = g.x("effort")
            g.d("effort", f"({command} - {f}) / {g.p('T_lag')}")
        else:
            f = g.local("f")
            g.line(f"{f} = {command}")
        g.apply("flange", f)
        g.aux("effort", f)
        g.power("source", "drive", f"{f} * {v}")

    def _u_max(self) -> float:
        assert self.u_max is not None  # only with a current loop
        return self.u_max

    def _emit_loop(self, g: Emitter, omega: str) -> None:
        di, dz, u = g.local("di"), g.local("dz"), g.local("u")
        g.call(
            (di, dz, u),
            "feed_twin.plant.current_loop.current_loop",
            (g.drive("OUT_EFFORT_CMD"), g.drive("OUT_ENABLED"), g.x("i"), g.x("z"), omega)
            + tuple(g.p(n) for n in ("gain", *CURRENT_LOOP_FIELDS)),
        )
        g.d("i", di)
        g.d("z", dz)
        tau = g.local("f")
        g.line(f"{tau} = {g.p('gain')} * {g.x('i')}")
        g.apply("flange", tau)
        g.aux("effort", tau)
        g.aux("u", u)
        ratio = g.p("emf_ratio")
        g.power("source", "drive", f"{u} * {g.x('i')} / {ratio}")
        g.power("loss", "copper", f"{g.p('R_s')} * {g.x('i')} ** 2 / {ratio}")
        g.stored("magnetic", f"0.5 * {g.p('L_s')} * {g.x('i')} ** 2 / {ratio}")
