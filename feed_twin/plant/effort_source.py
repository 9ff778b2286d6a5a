"""Ideal force or torque source behind a first-order current loop.

For drives where only the force command is known (the EMPS bench: force = gtau * vir): the
commanded effort f_cmd = gain * effort_cmd (0 while the drive is disabled) is reached through
    T_lag * df/dt = f_cmd - f     (T_lag > 0; the closed current loop as a first-order lag),
or f = f_cmd at once when T_lag = 0. The source delivers f*v into the axis.
Port: `flange` (rotational [rad, rad/s, N m] or translational [m, m/s, N], set by `domain`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, PortKind, StateSpec
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

    def __post_init__(self) -> None:
        require_finite("gain", self.gain)
        require_nonnegative("T_lag", self.T_lag)
        require_positive("f_max", self.f_max)

    def ports(self) -> dict[str, PortKind]:
        return {"flange": self.domain}

    def states(self) -> tuple[StateSpec, ...]:
        unit = "N m" if self.domain == "rotational" else "N"
        if self.T_lag > 0.0:
            return (StateSpec(name="effort", unit=unit, limit=self.f_max),)
        return ()

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, v = g.across("flange")
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
