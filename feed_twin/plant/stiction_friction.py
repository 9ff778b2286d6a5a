"""Stiction: a friction that holds the table at rest up to a holding force (elasto-plastic).

A sliding friction regularised around v = 0 (GuideFriction's smooth sign) cannot hold a load:
under any force below the Coulomb level the table creeps at a speed of order v_reg, so a
position loop settles with nothing left on the drive, while a real drive stands still holding
the current it had when the table stopped (the stiction band). This law holds it: the contact
asperities are a spring of deflection z (the presliding displacement, a few micrometres) that
follows the motion while the force they carry is below the holding force F_hold and slips
beyond it (the elasto-plastic model of Dupont et al., without its presliding creep):
    z_max = F_hold / k_s,
    dz/dt = 0 if z v > 0 and |z| >= z_max (slipping: the asperities are dragged along),
            v otherwise (stuck: they deflect with the table),
            minus r_slip (z - clip(z, -z_max, z_max)) (an RK4 stage that overshot falls back),
    F = k_s clip(z, -z_max, z_max) + d_s v [while |z| < z_max],
the flange receives -F. Sliding, F = F_hold sgn(v) (a Coulomb force); at rest F is whatever
force the table needs to stay, up to F_hold, taken up by a deflection F / k_s. Nothing in the
law is stiff: the switch costs no step size (only r_slip h < 2.78 for explicit RK4, r_slip h = 1
is plenty), and k_s with the moving mass m must keep h sqrt(k_s / m) small (the stuck table is
a mass on the asperity spring, damped by d_s).
Stored energy k_s clip(z)^2 / 2; loss F v - k_s clip(z) d(clip z)/dt (F_hold |v| sliding,
d_s v^2 stuck).
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange). State: `z` [m], 0 at
the start (nothing held).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotReader, StateSpec
from feed_twin.plant.effect_api import (
    MOVING_SPEEDS,
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Weights,
    last_direction,
    make_edit,
    moving,
)

DEFLECTION_LIMIT_M = 1e-2  # |z| above this is a runaway
# presliding stiffness and damping ratio the workflow gives a stiction it adds: a deflection of
# 10 um at a holding force of 100 N, an asperity spring damped at half the critical value
ADDED_K_S_N_M = 1e7
ADDED_DAMPING_RATIO = 0.5


@njit(error_model="numpy", forceinline=True)
def stiction_force(
    z: float, v: float, F_hold: float, k_s: float, d_s: float, r_slip: float
) -> tuple[float, float, float, float]:
    """(friction force F [N], dz/dt [m/s], stored energy [J], loss power [W])."""
    z_max = F_hold / k_s
    z_c = min(max(z, -z_max), z_max)
    stuck = abs(z) < z_max
    # slipping: dragged along; stuck or backing off: deflecting with the table
    rate = (0.0 if not stuck and z * v > 0.0 else v) - r_slip * (z - z_c)
    damping = d_s * v if stuck else 0.0
    f = k_s * z_c + damping
    stored = 0.5 * k_s * z_c * z_c
    loss = f * v - (k_s * z_c * rate if stuck else 0.0)
    return f, rate, stored, loss


def _held(m: Motion) -> dict[str, FloatArray]:
    """At rest the stuck table keeps the force it had when it stopped: the loop stops it short
    of the command (or past it, the EMPS loop's proportional velocity law overshoots), the same
    way after every move of one direction, so the held force follows the last direction.

    That holds where the command rests too (a dwell). Where the table stops while its command
    moves on (a reversal, or the creeping end of a jerk-limited stop), it is stuck while the
    drive's force swings through the holding band, and a twin whose friction slides reverses
    at once: there the residual follows the last direction with a size and sign of its own
    (a jerk-limited reversal sticks for 20-30 ms, about 2 F_hold against the twin; fitted as
    one with the dwells' held force, it hid the stiction of a record). So, with a command, the
    rest of each stop is split by the share of it the command rests too: held and stuck.
    """
    rest = 1.0 - moving(m)
    last = last_direction(m)
    if m.v_cmd_m_s is None:
        return {"held": last * rest}
    commanded = _stop_shares(m, rest, 1.0 - np.abs(np.tanh(m.v_cmd_m_s / m.speed_eps)))
    return {"held": last * rest * commanded, "stuck": last * rest * (1.0 - commanded)}


def _stop_shares(m: Motion, rest: FloatArray, command_rest: FloatArray) -> FloatArray:
    """On each stop of the table (a run of samples below last_direction's moving speed), the
    rest-weighted mean of `command_rest` over it; 0 while moving."""
    still = ~(np.abs(m.v_m_s) > MOVING_SPEEDS * m.speed_eps)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(np.int8), 0]))
    share = np.zeros_like(rest)
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        weight = float(np.sum(rest[a:b]))
        if weight > 0.0:
            share[a:b] = float(np.dot(rest[a:b], command_rest[a:b])) / weight
    return share


def _edit(doc: Document, cand: Weights) -> Edit:
    """Add StictionFriction on the table; it takes over the Coulomb part of the guide friction
    (the common part of both directions), so that the sliding force stays what it was."""
    fr = doc.friction()
    coulomb = 0.0
    if fr is not None:
        coulomb = min(doc.get(f"{fr}.F_c_pos"), doc.get(f"{fr}.F_c_neg"))
        for side in ("F_c_pos", "F_c_neg"):
            doc = doc.set(f"{fr}.{side}", doc.get(f"{fr}.{side}") - coulomb)
    f_hold = coulomb if coulomb > 0.0 else max(abs(cand.force("held")), 1e-3)
    doc, name = _with_stiction(doc, f_hold)
    slot = f"{name}.F_hold"
    own = [FreeParameter(name=slot, initial=f_hold, scale=f_hold, lower=0.0)]
    # re-fitted with the rigid-body parameters it trades off against (mass, friction)
    return make_edit(doc, own, {"F_hold_N": lambda v: v[slot]})


def _truth(doc: Document, p: Mapping[str, float]) -> Document:
    return _with_stiction(doc, float(p["F_hold_N"]))[0]


def _with_stiction(doc: Document, f_hold: float) -> tuple[Document, str]:
    """The document with a StictionFriction of holding force f_hold [N] on the table, its
    presliding spring ADDED_K_S_N_M damped at ADDED_DAMPING_RATIO of the table mass."""
    slot = doc.mass_slot()
    mass = doc.get(slot) if slot is not None else 1.0
    params = {
        "F_hold": f_hold,
        "k_s": ADDED_K_S_N_M,
        "d_s": 2.0 * ADDED_DAMPING_RATIO * float(np.sqrt(ADDED_K_S_N_M * mass)),
        "r_slip": 1.0 / doc.base_period(),
    }
    return doc.with_table_component("stiction", StictionFriction.TYPE, params)


@dataclass(frozen=True, kw_only=True)
class StictionFriction(Component):
    TYPE = "StictionFriction"
    PORTS = {"flange": "translational"}
    EFFECTS = (
        Effect(
            name="stiction",
            domain="effort",
            words="the drive keeps a holding force while the table stands still: friction "
            "holds the table at rest (stiction band) instead of letting it creep",
            parameters="F_hold",
            signature=_held,
            edit=_edit,
            truth=_truth,
        ),
    )

    F_hold: float  # holding (break-away) force, also the sliding force [N]
    k_s: float  # presliding stiffness of the contact [N/m]
    d_s: float  # presliding damping while stuck [N s/m]
    r_slip: float  # rate at which an overshoot past the holding deflection falls back [1/s]

    def __post_init__(self) -> None:
        require_nonnegative("F_hold", self.F_hold)
        require_positive("k_s", self.k_s)
        require_nonnegative("d_s", self.d_s)
        require_positive("r_slip", self.r_slip)

    def states(self) -> tuple[StateSpec, ...]:
        return (StateSpec(name="z", unit="m", limit=DEFLECTION_LIMIT_M),)

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"flange": slot("d_s")}

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, v = g.across("flange")
        f, rate, e, loss = g.local("f"), g.local("rate"), g.local("e"), g.local("loss")
        g.call(
            (f, rate, e, loss),
            "feed_twin.plant.stiction_friction.stiction_force",
            (g.x("z"), v, g.p("F_hold"), g.p("k_s"), g.p("d_s"), g.p("r_slip")),
        )
        g.d("z", rate)
        g.apply("flange", f"-{f}")
        g.aux("force", f)
        g.stored("asperities", e)
        g.power("loss", "friction", loss)
