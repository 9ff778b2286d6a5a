"""Guide-way friction: Coulomb + Stribeck + viscous, direction dependent, regularised.

Equation: the force into the flange is f = -F(v) with
    F(v) = [F_c(v) + dF_s * exp(-(v/v_s)^2)] * sgn(v/v_reg) + F_v(v) * v,
    F_c(v) = (F_c_pos + F_c_neg)/2 + (F_c_pos - F_c_neg)/2 * sgn(v/v_reg), likewise F_v(v),
with sgn the smooth sign function of feed_twin.core.smooth (a C2 quintic, exactly +/-1 for
|v| >= 15/8 v_reg) and exp(-x) written out (feed_twin.plant.expneg, no libm call in the loop),
so positive and negative motion can have their own Coulomb and viscous values (worn screws and
the EMPS bench are asymmetric) while F stays smooth. dF_s is the Stribeck excess of the breakaway
force over the Coulomb level, v_s its velocity scale.
Where the Stribeck term cannot change a bit it is not evaluated: for (v/v_s)^2 > CUT_X = 41
and dF_s < CUT_RATIO * min(F_c_pos, F_c_neg) = 16 min(...), dF_s exp(-(v/v_s)^2) < 2.6e-17 F_c,
below half a unit in the last place of F_c (>= 2^-54 F_c = 5.6e-17 F_c), so F_c + that term
rounds to F_c and the force is the same to the bit (tests/test_plant_friction_cut.py). Above
|v| = 6.4 v_s the exponential's polynomial is then skipped in every RK4 stage (its share of a
tick: docs/performance.md).
Why it is stable at the step size: near v = 0 the law is a damper of slope
c0 = (F_c + dF_s)/v_reg + F_v; an explicit RK4 step h on a body of effective mass m is stable for
h*c0/m < 2.78. `damping_bounds` reports c0 and the engine refuses a step that violates h*c0/m <
2.5, so the regularisation velocity v_reg must be chosen with the step (e.g. 1e-4 m/s for a
200 kg table at 62.5 us). The price is a creep velocity of order v_reg under sub-Coulomb forces.
A friction that changes over the record (the lubricant warming, a seal running in) is the law
times (1 + drift_per_s * age), age [s] the time since the run started (a state of its own,
d(age)/dt = 1, present only while drift_per_s is not 0, so a model without drift runs the code it
always ran): every term grows by the same share per second, which the workflow fits as the
effect `friction_drift` beside the friction's own terms (one parameter, its rate).
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numba import njit

from feed_twin.core.smooth import smooth_sign
from feed_twin.core.validate import require_nonnegative, require_positive, require_range
from feed_twin.plant.component import Component, Emitter, SlotReader, StateSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Signature,
    Weights,
    direction,
    free_parameter,
    make_edit,
    moving,
    slot_reader,
    symmetric,
)
from feed_twin.plant.expneg import exp_neg

# beyond x = (v/v_s)^2 > CUT_X the Stribeck term is below the last bit of F_c, provided that
# dF_s < CUT_RATIO * F_c: exp(-41) * 16 = 2.5e-17 < 2^-54 = 5.6e-17 (module docstring)
CUT_X = 41.0
CUT_RATIO = 16.0


@njit(error_model="numpy", forceinline=True)
def friction_force(
    v: float,
    F_c_pos: float,
    F_c_neg: float,
    F_v_pos: float,
    F_v_neg: float,
    dF_s: float,
    v_s: float,
    v_reg: float,
) -> float:
    """Friction force magnitude-with-sign F(v) [N]; the flange receives -F(v)."""
    sgn = smooth_sign(v, v_reg)
    F_c = 0.5 * (F_c_pos + F_c_neg) + 0.5 * (F_c_pos - F_c_neg) * sgn
    F_v = 0.5 * (F_v_pos + F_v_neg) + 0.5 * (F_v_pos - F_v_neg) * sgn
    # times the reciprocal of a parameter, which the compiled loop computes once (a division per
    # call would not leave the loop)
    r2 = (v * (1.0 / v_s)) ** 2
    # the second test depends on parameters alone: the compiled loop evaluates it once
    if dF_s == 0.0 or (r2 > CUT_X and dF_s < CUT_RATIO * min(F_c_pos, F_c_neg)):
        stribeck = 0.0  # exactly what adding dF_s * exp(-r2) to F_c would leave
    else:
        stribeck = dF_s * exp_neg(r2)
    return (F_c + stribeck) * sgn + F_v * v


# [1/s] a drift rate's bound: the friction doubling (or gone) within a second is no drift
DRIFT_LIMIT_PER_S = 1.0
AGE_LIMIT_S = 1e9  # [s] the drift's age state: above this is a runaway

STRIBECK_SPEEDS_M_S = (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02, 0.03)  # searched v_s
# what the workflow adds to a model without guide friction (all zero, v_reg of a fitting twin)
ADDED_FRICTION = {
    "F_c_pos": 0.0,
    "F_c_neg": 0.0,
    "F_v_pos": 0.0,
    "F_v_neg": 0.0,
    "dF_s": 0.0,
    "v_s": 0.005,
    "v_reg": 1e-3,
}


def with_friction(doc: Document) -> tuple[Document, str]:
    """The document with a GuideFriction on the table (all zero) if it has none; its name."""
    fr = doc.friction()
    if fr is not None:
        return doc, fr
    return doc.with_table_component("friction", GuideFriction.TYPE, ADDED_FRICTION)


def _tied(doc: Document, tied: str) -> tuple[Document, str]:
    """The symmetric document with the forward/backward pair of `tied` (F_c, F_v) as one."""
    doc, fr = with_friction(doc)
    return symmetric(doc).tie(f"{fr}.{tied}", (f"{fr}.{tied}_pos", f"{fr}.{tied}_neg")), fr


def _coulomb_edit(doc: Document, cand: Weights) -> Edit:
    doc, fr = _tied(doc, "F_c")
    # the weight is the friction the twin lacks (measured minus twin), on top of what it has
    fc = max(doc.get(f"{fr}.F_c") + cand.force("sign_v"), 1e-3)
    doc = doc.set(f"{fr}.F_c", fc)
    own = [free_parameter(doc, f"{fr}.F_c", fc)]
    return make_edit(doc, own, {"F_c_N": slot_reader(f"{fr}.F_c")})


def _viscous_edit(doc: Document, cand: Weights) -> Edit:
    doc, fr = _tied(doc, "F_v")
    guess = max(doc.get(f"{fr}.F_v") + cand.force("v"), 0.0)
    doc = doc.set(f"{fr}.F_v", guess)
    own = [free_parameter(doc, f"{fr}.F_v", guess)]
    return make_edit(doc, own, {"F_v_N_s_m": slot_reader(f"{fr}.F_v")})


def _stribeck_edit(doc: Document, cand: Weights) -> Edit:
    doc, fr = with_friction(doc)
    doc = symmetric(doc)
    vs = float(cand.variant.split("=")[1].split()[0]) if cand.variant else 0.005
    ds = max(doc.get(f"{fr}.dF_s") + cand.force("stribeck"), 1e-3)
    doc = doc.set(f"{fr}.dF_s", ds).set(f"{fr}.v_s", vs)
    own = [
        free_parameter(doc, f"{fr}.dF_s"),
        free_parameter(doc, f"{fr}.v_s", lower=1e-4, floor=1e-3),
    ]
    report = {"dF_s_N": slot_reader(f"{fr}.dF_s"), "v_s_m_s": slot_reader(f"{fr}.v_s")}
    return make_edit(doc, own, report)


def _asymmetric_edit(doc: Document, cand: Weights) -> Edit:
    """Forward and backward friction apart. Coulomb is split only once Coulomb friction is in
    the model: a split Coulomb force alone would look like a constant force while moving."""
    del cand
    doc, fr = with_friction(doc)
    has_coulomb = doc.get(f"{fr}.F_c_pos") > 0.0 or doc.get(f"{fr}.F_c_neg") > 0.0
    doc = doc.untie().mark_asymmetric(fr)
    names = ("F_v_pos", "F_v_neg") + (("F_c_pos", "F_c_neg") if has_coulomb else ())
    own = [free_parameter(doc, f"{fr}.{n}") for n in names]
    report = {n: slot_reader(f"{fr}.{n}") for n in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg")}
    # one more value per direction-split term than the symmetric model had
    return make_edit(doc, own, report, added=len(names) // 2)


DRIFT_SIZES = ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg", "dF_s")  # the terms a drift grows


def _drift_edit(doc: Document, cand: Weights) -> Edit:
    """Every term of the guides' friction grown by the same share per second (module
    docstring): one parameter, the rate, fitted with the friction's own terms (they interact).
    The ranking's weights start it: a friction F_0 (1 + r t) that the model holds at its mean
    over the record, F_0 (1 + r t_mid), leaves F_0 r (t - t_mid) times the law's shape, so the
    weight over the friction at the record's start is the rate. The terms stay as they are: a
    term the rounds fitted (at its mean) is fitted again with the rate (analysis.trials), a
    term of the data sheet they did not touch is the machine's at the start of the run, which
    is where the drift counts from. A model whose guides have no friction has nothing to drift."""
    fr = doc.friction()
    if fr is None or not any(doc.get(f"{fr}.{n}") > 0.0 for n in DRIFT_SIZES):
        raise LookupError("the model has no guide friction to drift")
    slot = f"{fr}.drift_per_s"
    t_mid = float(cand.variant.split("=")[1].split()[0]) if cand.variant else 0.0
    coulomb = 0.5 * (doc.get(f"{fr}.F_c_pos") + doc.get(f"{fr}.F_c_neg"))
    viscous = 0.5 * (doc.get(f"{fr}.F_v_pos") + doc.get(f"{fr}.F_v_neg"))
    # the better-held of the two terms' weights, over that term at the record's start
    weight, term = (
        (cand.force("t_sign_v"), coulomb) if coulomb > 0.0 else (cand.force("t_v"), viscous)
    )
    start = term - weight * t_mid
    rate = float(doc.component(fr)["params"].get("drift_per_s", 0.0)) + (
        weight / start if term > 0.0 and start > 0.0 else 0.0
    )
    if rate == 0.0:
        rate = 0.01  # [1/s] a start the fit moves (0 would compile the model without drift)
    rate = min(max(rate, -0.5 * DRIFT_LIMIT_PER_S), 0.5 * DRIFT_LIMIT_PER_S)
    doc = doc.set(slot, rate)
    own = [
        FreeParameter(
            name=slot, initial=rate, scale=max(abs(rate), 0.01),
            lower=-DRIFT_LIMIT_PER_S, upper=DRIFT_LIMIT_PER_S,
        )
    ]  # fmt: skip
    return make_edit(doc, own, {"rate_per_s": slot_reader(slot)})


def _drift_choices(m: Motion) -> list[tuple[str, Signature]]:
    """A friction grown by r t, held at its mean: Coulomb's sign(v) and viscous's v times the
    time from the record's middle (one variant, which carries that middle to the edit)."""
    t_mid = 0.5 * (float(m.t_s[0]) + float(m.t_s[-1]))

    def signature(mm: Motion) -> dict[str, np.ndarray]:
        # the age the twin's drift counts from the run's start (the record's first sample)
        centred = mm.t_s - mm.t_s[0] - t_mid + float(m.t_s[0])
        return {"t_sign_v": centred * direction(mm), "t_v": centred * mm.v_m_s}

    return [(f"t_mid = {t_mid - float(m.t_s[0]):.6g} s", signature)]


def _drift_truth(doc: Document, p: Mapping[str, float]) -> Document:
    doc, fr = with_friction(doc)
    return doc.set(f"{fr}.drift_per_s", p["rate_per_s"])


def _truth(doc: Document, p: Mapping[str, float]) -> Document:
    """The friction a synthetic record hides: any of F_c_N, F_v_N_s_m (both directions),
    dF_s_N with v_s_m_s, or the per-direction F_c_pos, F_c_neg, F_v_pos, F_v_neg."""
    doc, fr = with_friction(doc)
    for key, fields in (("F_c_N", ("F_c_pos", "F_c_neg")), ("F_v_N_s_m", ("F_v_pos", "F_v_neg"))):
        for name in fields if key in p else ():
            doc = doc.set(f"{fr}.{name}", p[key])
    if "dF_s_N" in p:
        doc = doc.set(f"{fr}.dF_s", p["dF_s_N"]).set(f"{fr}.v_s", p["v_s_m_s"])
    for name in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg"):
        if name in p:
            doc = doc.set(f"{fr}.{name}", p[name])
    return doc


def _stribeck_choices(m: Motion) -> list[tuple[str, Signature]]:
    def make(vs: float) -> Signature:
        return lambda mm: {"stribeck": direction(mm) * np.exp(-((mm.v_m_s / vs) ** 2))}

    return [(f"v_s = {vs:g} m/s", make(vs)) for vs in STRIBECK_SPEEDS_M_S]


@dataclass(frozen=True, kw_only=True)
class GuideFriction(Component):
    TYPE = "GuideFriction"
    PORTS = {"flange": "translational"}
    EFFECTS = (
        Effect(
            name="coulomb_friction",
            domain="effort",
            words="a constant friction force that changes sign with the direction of motion",
            parameters="F_c",
            signature=lambda m: {"sign_v": direction(m)},
            edit=_coulomb_edit,
            truth=_truth,
        ),
        Effect(
            name="viscous_friction",
            domain="effort",
            words="a friction force that grows in proportion to speed (lubricant, seals)",
            parameters="F_v",
            signature=lambda m: {"v": m.v_m_s},
            edit=_viscous_edit,
            truth=_truth,
        ),
        Effect(
            name="stribeck_friction",
            domain="effort",
            words="extra break-away friction at low speed that fades as speed rises (stick-slip)",
            parameters="dF_s, v_s",
            choices=_stribeck_choices,
            edit=_stribeck_edit,
            truth=_truth,
        ),
        Effect(
            name="asymmetric_friction",
            domain="effort",
            words="friction that differs between the two directions of travel (worn or "
            "fatigued screw, uneven preload)",
            parameters="F_c_pos, F_c_neg, F_v_pos, F_v_neg",
            signature=lambda m: {"abs_v": np.abs(m.v_m_s), "moving": moving(m)},
            edit=_asymmetric_edit,
            truth=_truth,
        ),
        Effect(
            name="friction_drift",
            domain="effort",
            words="a friction that changes over the record, every term by the same share per "
            "second (the lubricant warming, a seal running in)",
            parameters="drift_per_s",
            choices=_drift_choices,
            edit=_drift_edit,
            truth=_drift_truth,
        ),
    )
    STATE_OUTPUTS = {"friction_force": "-force"}  # force is F(v); the table receives -F

    F_c_pos: float  # Coulomb force in positive motion [N]
    F_c_neg: float  # Coulomb force in negative motion [N]
    F_v_pos: float  # viscous coefficient in positive motion [N s/m]
    F_v_neg: float  # viscous coefficient in negative motion [N s/m]
    dF_s: float  # Stribeck excess of the breakaway force over Coulomb [N]
    v_s: float  # Stribeck velocity [m/s]
    v_reg: float  # regularisation velocity of the sign function [m/s]
    # every term grows by this share of itself per second of the run (0: no drift) [1/s]
    drift_per_s: float = 0.0

    def __post_init__(self) -> None:
        for name in DRIFT_SIZES:
            require_nonnegative(name, getattr(self, name))
        require_positive("v_s", self.v_s)
        require_positive("v_reg", self.v_reg)
        require_range("drift_per_s", self.drift_per_s, -DRIFT_LIMIT_PER_S, DRIFT_LIMIT_PER_S)

    def slots(self) -> dict[str, float]:
        # without a drift no drift slot: the code it would scale is not generated (emit)
        out = super().slots()
        if self.drift_per_s == 0.0:
            del out["drift_per_s"]
        return out

    def states(self) -> tuple[StateSpec, ...]:
        if self.drift_per_s == 0.0:
            return ()
        return (StateSpec(name="age", unit="s", limit=AGE_LIMIT_S),)

    def force(self, v: float) -> float:
        """F(v) [N] in plain Python (the flange receives -F(v))."""
        return friction_force.py_func(
            v,
            self.F_c_pos,
            self.F_c_neg,
            self.F_v_pos,
            self.F_v_neg,
            self.dF_s,
            self.v_s,
            self.v_reg,
        )

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        c0 = (max(slot("F_c_pos"), slot("F_c_neg")) + slot("dF_s")) / slot("v_reg")
        return {"flange": c0 + max(slot("F_v_pos"), slot("F_v_neg"))}

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        _, v = g.across("flange")
        f = g.local("f")
        g.call(
            (f,),
            "feed_twin.plant.guide_friction.friction_force",
            (v,)
            + tuple(g.p(n) for n in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg"))
            + (g.p("dF_s"), g.p("v_s"), g.p("v_reg")),
        )
        if self.drift_per_s != 0.0:
            g.d("age", "1.0")
            g.line(f"{f} = {f} * (1.0 + {g.p('drift_per_s')} * {g.x('age')})")
        g.apply("flange", f"-{f}")
        g.aux("force", f)
        g.power("loss", "friction", f"{f} * {v}")
