"""Guide-way friction: Coulomb + Stribeck + viscous, direction dependent, regularised.

Equation: the force into the flange is f = -F(v) with
    F(v) = [F_c(v) + dF_s * exp(-(v/v_s)^2)] * sgn(v/v_reg) + F_v(v) * v,
    F_c(v) = (F_c_pos + F_c_neg)/2 + (F_c_pos - F_c_neg)/2 * sgn(v/v_reg), likewise F_v(v),
with sgn the smooth sign function of feed_twin.plant.smooth (a C2 quintic, exactly +/-1 for
|v| >= 15/8 v_reg) and exp(-x) written out (feed_twin.plant.expneg, no libm call in the loop),
so positive and negative motion can have their own Coulomb and viscous values (worn screws and
the EMPS bench are asymmetric) while F stays smooth. dF_s is the Stribeck excess of the breakaway
force over the Coulomb level, v_s its velocity scale.
Where the Stribeck term cannot change a bit it is not evaluated: for (v/v_s)^2 > CUT_X = 41
and dF_s < CUT_RATIO * min(F_c_pos, F_c_neg) = 16 min(...), dF_s exp(-(v/v_s)^2) < 2.6e-17 F_c,
below half a unit in the last place of F_c (>= 2^-54 F_c = 5.6e-17 F_c), so F_c + that term
rounds to F_c and the force is the same to the bit (tests/test_plant_friction_cut.py). Above
|v| = 6.4 v_s the exponential's polynomial is then skipped in every RK4 stage: 6 % of a tick of
axis_default on the batch benchmark's 50 mm/s move (docs/architecture.md).
Why it is stable at the step size: near v = 0 the law is a damper of slope
c0 = (F_c + dF_s)/v_reg + F_v; an explicit RK4 step h on a body of effective mass m is stable for
h*c0/m < 2.78. `damping_bounds` reports c0 and the engine refuses a step that violates h*c0/m <
2.5, so the regularisation velocity v_reg must be chosen with the step (e.g. 1e-4 m/s for a
200 kg table at 62.5 us). The price is a creep velocity of order v_reg under sub-Coulomb forces.
Port: `flange` (translational: s [m], v [m/s], f [N] into the flange).
"""

from __future__ import annotations

from dataclasses import dataclass

from numba import njit

from feed_twin.io.config import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotReader
from feed_twin.plant.expneg import exp_neg
from feed_twin.plant.smooth import smooth_sign

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


@dataclass(frozen=True, kw_only=True)
class GuideFriction(Component):
    TYPE = "GuideFriction"
    PORTS = {"flange": "translational"}
    STATE_OUTPUTS = {"friction_force": "-force"}  # force is F(v); the table receives -F

    F_c_pos: float  # Coulomb force in positive motion [N]
    F_c_neg: float  # Coulomb force in negative motion [N]
    F_v_pos: float  # viscous coefficient in positive motion [N s/m]
    F_v_neg: float  # viscous coefficient in negative motion [N s/m]
    dF_s: float  # Stribeck excess of the breakaway force over Coulomb [N]
    v_s: float  # Stribeck velocity [m/s]
    v_reg: float  # regularisation velocity of the sign function [m/s]

    def __post_init__(self) -> None:
        for name in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg", "dF_s"):
            require_nonnegative(name, getattr(self, name))
        require_positive("v_s", self.v_s)
        require_positive("v_reg", self.v_reg)

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
        g.apply("flange", f"-{f}")
        g.aux("force", f)
        g.power("loss", "friction", f"{f} * {v}")
