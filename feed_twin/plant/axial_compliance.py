"""Axial compliance of the feed drive: support bearings, screw shaft and nut in series.

Equation: with delta = s_a - s_b (screw-side flange a, nut flange b) the cut force a -> b is
    f = k(x) * delta + d * (v_a - v_b),   1/k(x) = 1/k_bearing + 1/k_screw(x) + 1/k_nut,
where x = x_0 + s_b is the nut's distance from the driven-end (fixed) bearing and
    fixed-fixed:  k_screw(x) = E*A*L / (x * (L - x)),     fixed-free:  k_screw(x) = E*A / x,
with A = pi*d_root^2/4 and L the bearing span. x is clamped to [x_min, L - x_min] (fixed-fixed)
or [x_min, L] (fixed-free): at a bearing the formula's stiffness goes to infinity while the real
one is limited by the bearing and the screw's end journal; x_min (typically a nut length) keeps
the stiffness finite. The stored energy V = k(x)*delta^2/2 depends on x, so the nut also feels
-dV/dx = -k'(x)*delta^2/2: with it the element is conservative (energy test), without it it
would create energy whenever the nut moves under load. That force is tiny (micro-newtons).
Periodic lead error: the screw's thread deviates from the ideal helix by
e(s_a) = A*sin(2*pi*s_a/P + phase) (P = the lead for the once-per-revolution error of the
accuracy classes, s_a = r*phi the ideal nut travel), so the spring sees delta = s_a + e(s_a) - s_b,
and the screw side receives -f*(1 + e'(s_a)) (virtual work: still conservative).
Lost motion of the nut (`gap` > 0, default 0): the spring acts on delta less the half gap
b = gap/2 beyond it and not at all within it, f_e = k(x) * (delta -+ b) for |delta| > b, 0
inside, the damper only in contact and limited so that f never changes the sign of f_e (a
contact pushes, never pulls; plant.backlash's law). It is the dead zone of a Backlash in series
with the spring without a nut mass between them: a Backlash needs that mass, and a nut of a few
kilograms on the contact would oscillate at kilohertz, many sub-steps per tick of a 1 kHz twin.
The bearing arrangement is structure, not a parameter: the generated code passes the law a
constant (`fixed_fixed_flag`), so the compiled loop has no branch on it.
Ports: `a`, `b` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, Quantity, SlotReader, SlotSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Report,
    Weights,
    first_of,
    make_edit,
    motor_angle,
)


def fixed_fixed_flag(arrangement: str) -> str:
    """The `fixed_fixed` argument of `axial_stiffness` for an arrangement, as generated code."""
    return "1.0" if arrangement == "fixed-fixed" else "0.0"


@njit(error_model="numpy", forceinline=True)
def axial_stiffness(
    x: float, L: float, EA: float, k_bearing: float, k_nut: float, fixed_fixed: float, x_min: float
) -> tuple[float, float]:
    """(k(x) [N/m], dk/dx [N/m^2]) of bearings, screw section and nut in series."""
    if fixed_fixed > 0.5:
        lo, hi = x_min, L - x_min
    else:
        lo, hi = x_min, L
    clamped = x < lo or x > hi
    xc = min(max(x, lo), hi)
    # products with reciprocals of parameters: the compiled loop computes those once
    if fixed_fixed > 0.5:
        inv_EAL = 1.0 / (EA * L)
        compliance_screw = xc * (L - xc) * inv_EAL
        dcompliance = (L - 2.0 * xc) * inv_EAL
    else:
        compliance_screw = xc * (1.0 / EA)
        dcompliance = 1.0 / EA
    if clamped:
        dcompliance = 0.0
    k = 1.0 / (1.0 / k_bearing + compliance_screw + 1.0 / k_nut)
    return k, -k * k * dcompliance


@njit(error_model="numpy", forceinline=True)
def lead_error(
    s_a: float, amplitude: float, wavenumber: float, phase: float
) -> tuple[float, float]:
    """(e(s_a) [m], de/ds_a [-]) of a sinusoidal lead error."""
    if amplitude == 0.0:  # the usual case: skip the trigonometry in the hot loop
        return 0.0, 0.0
    arg = wavenumber * s_a + phase
    return amplitude * math.sin(arg), amplitude * wavenumber * math.cos(arg)


@njit(error_model="numpy", forceinline=True)
def axial_force(
    delta: float,
    delta_rate: float,
    x: float,
    L: float,
    EA: float,
    k_bearing: float,
    k_nut: float,
    fixed_fixed: float,
    x_min: float,
    d: float,
    gap: float,
) -> tuple[float, float, float, float, float]:
    """(cut force a->b, extra force on b from dk/dx, stiffness, stored energy, loss power)."""
    k, dk = axial_stiffness(x, L, EA, k_bearing, k_nut, fixed_fixed, x_min)
    damping = d * delta_rate
    if gap > 0.0:
        return _lost_motion(delta, delta_rate, 0.5 * gap, k, dk, damping)
    return (
        k * delta + damping,
        -0.5 * dk * delta * delta,
        k,
        0.5 * k * delta * delta,
        damping * delta_rate,
    )


@njit(error_model="numpy", forceinline=True)
def _lost_motion(
    delta: float, delta_rate: float, half: float, k: float, dk: float, damping: float
) -> tuple[float, float, float, float, float]:
    """axial_force's terms with the nut's lost motion `half` either side (module docstring)."""
    if delta > half:
        spring = delta - half
        f = max(k * spring + damping, 0.0)
    elif delta < -half:
        spring = delta + half
        f = min(k * spring + damping, 0.0)
    else:
        return 0.0, 0.0, k, 0.0, 0.0
    energy = 0.5 * k * spring * spring
    return f, -0.5 * dk * spring * spring, k, energy, (f - k * spring) * delta_rate


def axial_rigidity(E: float, d_root: float) -> float:
    """EA [N] of a screw of root diameter d_root [m] and Young's modulus E [Pa]."""
    return E * math.pi * d_root**2 / 4.0


def _set_axial_rigidity(params: dict[str, Any], value: float) -> None:
    # the root diameter stays: the fitted EA is stored as Young's modulus
    params["E"] = float(value) / (math.pi * float(params["d_root"]) ** 2 / 4.0)


def _screw_lead(doc: Document) -> float:
    screw = first_of(doc, "BallScrew", "whose lead is the lead error's period")
    return doc.get(f"{screw}.lead")


def _lead_error_edit(doc: Document, cand: Weights) -> Edit:
    """A once-per-revolution lead error in the axial compliance; amplitude and phase fitted.

    A linear scale reads the table at s + e(s), the twin at s: the position residual
    (twin minus measured) is -A sin(2 pi s / P + psi), so (sin, cos) weights (s, c) give
    A = hypot(s, c) and psi = atan2(-c, -s).
    """
    name = first_of(doc, AxialCompliance.TYPE, "to carry a lead error")
    lead = _screw_lead(doc)
    s_w, c_w = cand.coefficients.get("sin", 0.0), cand.coefficients.get("cos", 0.0)
    amplitude = max(math.hypot(s_w, c_w), 1e-9)
    phase = math.atan2(-c_w, -s_w)
    doc = _with_lead_error(doc, name, lead, amplitude, phase)
    own = [
        FreeParameter(
            name=f"{name}.lead_error_amplitude", initial=amplitude, scale=amplitude, lower=0.0
        ),
        FreeParameter(name=f"{name}.lead_error_phase", initial=phase, scale=1.0),
    ]
    report: Report = {
        "amplitude_m": lambda v: v[f"{name}.lead_error_amplitude"],
        "phase_rad": lambda v: v[f"{name}.lead_error_phase"],
        "period_m": lambda v: lead,
    }
    return make_edit(doc, own, report, interacts=False)


def _with_lead_error(
    doc: Document, name: str, lead: float, amplitude: float, phase: float
) -> Document:
    doc = doc.set_raw(name, "lead_error_period", lead)
    return doc.set(f"{name}.lead_error_amplitude", amplitude).set(f"{name}.lead_error_phase", phase)


def _lead_error_truth(doc: Document, p: Mapping[str, float]) -> Document:
    name = first_of(doc, AxialCompliance.TYPE, "to carry a lead error")
    return _with_lead_error(doc, name, _screw_lead(doc), p["amplitude_m"], p["phase_rad"])


def _stiffness_edit(doc: Document, cand: Weights) -> Edit:
    """The axial rigidity EA of the screw and the support-bearing stiffness are fitted.

    The axial compliance is 1/k(x) = 1/k_bearing + c_screw(x)/EA + 1/k_nut: the
    position-dependent part identifies EA, the constant part the bearing (the nut's share stays
    nominal: a constant compliance cannot tell the two apart). Both are fitted in the log
    (scaled to order 1 by their nominal values): the deflection goes with their inverses and
    the truth may be a factor of several away, where a linear parametrisation left the trust
    region crawling. The screw's root diameter stays fixed; EA is stored as Young's modulus.
    """
    del cand
    name = first_of(doc, AxialCompliance.TYPE, "(screw) whose stiffness could vary")
    slots = (f"{name}.k_bearing", f"{name}.EA")
    own = [
        FreeParameter(name=slot, initial=doc.get(slot), scale=doc.get(slot), lower=0.0, log=True)
        for slot in slots
    ]
    report: Report = {"k_bearing_N_m": lambda v: v[slots[0]], "EA_N": lambda v: v[slots[1]]}
    return make_edit(doc, own, report, interacts=False)


def _stiffness_truth(doc: Document, p: Mapping[str, float]) -> Document:
    name = first_of(doc, AxialCompliance.TYPE, "(screw) whose stiffness could vary")
    return doc.set(f"{name}.k_bearing", p["k_bearing_N_m"]).set(f"{name}.EA", p["EA_N"])


def _stiffness_signature(m: Motion) -> dict[str, FloatArray]:
    # the table lags the nut by F * c(x): a screw held at one end (fixed-free) has c linear
    # in the distance to the bearing, one held at both ends (fixed-fixed) c ~ x (L - x); a
    # quadratic in the position covers both (the constant part: bearings and nut). The twin's
    # effort stands for the axial load F.
    assert m.effort_sim is not None
    s = (m.x_m - m.x_m.mean()) / max(float(np.ptp(m.x_m)), 1e-9)
    f = m.effort_sim
    return {"f": f, "f_x": f * s, "f_x2": f * s * s}


@dataclass(frozen=True, kw_only=True)
class AxialCompliance(Component):
    TYPE = "AxialCompliance"
    PORTS = {"a": "translational", "b": "translational"}
    COMPUTED_SLOTS = {
        "EA": SlotSpec(unit="N", low=0.0, low_open=True),  # E pi d_root^2 / 4
        "lead_error_wavenumber": SlotSpec(unit="rad/m", low=0.0),  # 2 pi / period, 0: none
    }
    EFFECTS = (
        Effect(
            name="lead_error",
            domain="position",
            words="a position error that repeats once per screw revolution (pitch error, "
            "eccentricity)",
            parameters="lead_error_amplitude, lead_error_phase",
            needs=("lead_m",),
            signature=lambda m: {"sin": np.sin(motor_angle(m)), "cos": np.cos(motor_angle(m))},
            edit=_lead_error_edit,
            truth=_lead_error_truth,
        ),
        Effect(
            name="position_dependent_stiffness",
            domain="position",
            words="the table lags more under load in mid-travel than near the bearings: the "
            "screw's axial stiffness depends on the table position",
            parameters="k_bearing, EA",
            needs=("effort_sim",),
            signature=_stiffness_signature,
            edit=_stiffness_edit,
            truth=_stiffness_truth,
        ),
    )
    QUANTITIES = {
        "EA": Quantity(
            stored_as=("E", "d_root"),
            read=lambda params: axial_rigidity(float(params["E"]), float(params["d_root"])),
            write=_set_axial_rigidity,
        )
    }

    arrangement: Literal["fixed-fixed", "fixed-free"]  # bearing arrangement of the screw
    E: float  # Young's modulus of the screw [Pa] (steel about 210e9)
    d_root: float  # root diameter of the screw [m]
    L: float  # span between the support bearings [m]
    x_0: float  # nut distance from the driven-end bearing when s_b = 0 [m]
    x_min: float  # closest nut-to-bearing distance used in k_screw(x) [m]
    k_bearing: float  # axial stiffness of the support bearing set [N/m]
    k_nut: float  # axial stiffness of the preloaded nut [N/m]
    d: float  # axial damping [N s/m]
    lead_error_amplitude: float = 0.0  # amplitude A of the periodic lead error [m]; 0: none
    lead_error_period: float | None = None  # its period P in nut travel [m], usually the lead
    lead_error_phase: float = 0.0  # its phase [rad]
    gap: float = 0.0  # lost motion of the nut, total [m] (module docstring); 0: none

    def __post_init__(self) -> None:
        require_positive("E", self.E)
        require_positive("d_root", self.d_root)
        require_positive("L", self.L)
        require_positive("x_min", self.x_min)
        if self.x_min >= 0.5 * self.L:
            raise ValueError(f"x_min = {self.x_min!r}: must be < L/2 = {0.5 * self.L!r}")
        require_nonnegative("x_0", self.x_0)
        if self.x_0 > self.L:
            raise ValueError(f"x_0 = {self.x_0!r}: must lie within the bearing span L = {self.L!r}")
        require_positive("k_bearing", self.k_bearing)
        require_positive("k_nut", self.k_nut)
        require_nonnegative("d", self.d)
        require_nonnegative("lead_error_amplitude", self.lead_error_amplitude)
        require_nonnegative("gap", self.gap)
        if self.lead_error_period is not None:
            require_positive("lead_error_period", self.lead_error_period)
        elif self.lead_error_amplitude > 0.0:
            raise ValueError(
                f"lead_error_period = None: a lead error of amplitude "
                f"{self.lead_error_amplitude!r} needs its period"
            )

    def slots(self) -> dict[str, float]:
        return {
            "L": self.L,
            "EA": axial_rigidity(self.E, self.d_root),
            "x_0": self.x_0,
            "x_min": self.x_min,
            "k_bearing": self.k_bearing,
            "k_nut": self.k_nut,
            "d": self.d,
            "lead_error_amplitude": self.lead_error_amplitude,
            "lead_error_wavenumber": (
                0.0 if self.lead_error_period is None else 2.0 * math.pi / self.lead_error_period
            ),
            "lead_error_phase": self.lead_error_phase,
            "gap": self.gap,
        }

    def stiffness(self, s_b: float) -> float:
        """k(x) [N/m] at nut flange position s_b [m] (plain Python, for analysis and tests)."""
        slots = self.slots()
        k, _ = axial_stiffness.py_func(
            self.x_0 + s_b,
            slots["L"],
            slots["EA"],
            self.k_bearing,
            self.k_nut,
            float(fixed_fixed_flag(self.arrangement)),
            self.x_min,
        )
        return k

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        return {"a": slot("d"), "b": slot("d")}

    def stiffness_bound(self, slot: SlotReader) -> float:
        # bearings and nut in series: the screw section only adds compliance (axial_stiffness)
        return 1.0 / (1.0 / slot("k_bearing") + 1.0 / slot("k_nut"))

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        s_a, v_a = g.across("a")
        s_b, v_b = g.across("b")
        err, slope = g.local("lead_error"), g.local("lead_error_slope")
        g.call(
            (err, slope),
            "feed_twin.plant.axial_compliance.lead_error",
            (
                s_a,
                g.p("lead_error_amplitude"),
                g.p("lead_error_wavenumber"),
                g.p("lead_error_phase"),
            ),
        )
        f, f_x, k, e, loss = (g.local(n) for n in ("f", "f_x", "k", "e", "loss"))
        g.call(
            (f, f_x, k, e, loss),
            "feed_twin.plant.axial_compliance.axial_force",
            (
                f"{s_a} + {err} - {s_b}",
                f"{v_a} * (1.0 + {slope}) - {v_b}",
                f"{g.p('x_0')} + {s_b}",
                g.p("L"),
                g.p("EA"),
                g.p("k_bearing"),
                g.p("k_nut"),
                fixed_fixed_flag(self.arrangement),
                g.p("x_min"),
                g.p("d"),
                g.p("gap"),
            ),
        )
        g.apply("a", f"-{f} * (1.0 + {slope})")
        g.apply("b", f"{f} + {f_x}")
        g.aux("force", f)
        g.aux("lead_error", err)
        g.aux("stiffness", k)
        g.stored("spring", e)
        g.power("loss", "damping", loss)
