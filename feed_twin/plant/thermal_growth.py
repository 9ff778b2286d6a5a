"""Thermal elongation of the ball screw: the slowly growing position error of a warming axis.

The nut's friction and the bearings heat the screw while it turns. The temperature rise dT [K]
of the screw section between the fixed (driven-end) bearing and the nut follows a first-order
law driven by the travel speed,
    d(dT)/dt = heating * |v_a| - dT / tau,
(heating [K/m]: temperature rise per metre travelled while the screw is still cold; tau [s]:
thermal time constant of the screw, tens of minutes; the steady rise at speed v is
heating * tau * |v|). The heated section of length x = x_0 + s_a lengthens by
    e = alpha * dT * x            (alpha: thermal expansion coefficient, steel about 11.5e-6 1/K),
so for a given screw angle the nut sits e further from the fixed bearing. The element sits in
parallel with the AxialCompliance it accompanies (same ports a, b and the same geometry) and
adds the force that compliance's spring k(x) feels from the extra elongation,
    f = k(x) * e,   applied -f at a (screw side) and +f at b (nut side),
so together they act as one spring of stiffness k(x) stretched by s_a + e - s_b: a loop closed on
the motor encoder (semi-closed loop) leaves the table off by e, which a linear scale sees.
The thermal force does work on the mechanism: source power f * (v_b - v_a).
Ports: `a`, `b` (translational: s [m], v [m/s], f [N]). State: `dT` [K], starting cold (0).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.axial_compliance import AxialCompliance, fixed_fixed_flag
from feed_twin.plant.component import Component, Emitter, StateSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Weights,
    make_edit,
)

ALPHA_STEEL = 11.5e-6  # [1/K] linear thermal expansion of screw steel
TEMPERATURE_LIMIT_K = 500.0  # |dT| above this is a runaway
# slots of the accompanying compliance that its stiffness k(x) is computed from
STIFFNESS_SLOTS = ("L", "EA", "x_0", "x_min", "k_bearing", "k_nut")


@njit(error_model="numpy", forceinline=True)
def temperature_rate(dT: float, v: float, heating: float, tau: float) -> float:
    """d(dT)/dt [K/s] of the screw's temperature rise at travel speed v [m/s]."""
    return heating * abs(v) - dT / tau


@njit(error_model="numpy", forceinline=True)
def elongation(dT: float, x: float, alpha: float) -> float:
    """Thermal elongation [m] of the heated length x [m] at temperature rise dT [K]."""
    return alpha * dT * x


TAU_DEFAULT_S = 1800.0  # [s] thermal time constant of a ball screw (tens of minutes)
# the accompanying compliance's parameters a ThermalGrowth the workflow adds copies
GEOMETRY = ("arrangement", "E", "d_root", "L", "x_0", "x_min", "k_bearing", "k_nut")


def with_thermal_growth(
    doc: Document, heating: float, *, tau: float = TAU_DEFAULT_S, alpha: float = ALPHA_STEEL
) -> tuple[Document, str]:
    """The document with thermal growth of the screw (or its heating set); (doc, heating slot).

    The ThermalGrowth goes in parallel with the model's (first) AxialCompliance, with that
    compliance's geometry, so the pair acts as one spring stretched by the screw's thermal
    elongation. Only the heating rate [K/m] is fitted: a record much shorter than the thermal
    time constant sees dT grow in proportion to the distance travelled, heating * D(t), so the
    time constant is not identifiable from it and stays at its default.
    """
    existing = doc.of_type(ThermalGrowth.TYPE)
    if existing:
        return doc.set(f"{existing[0]}.heating", heating), f"{existing[0]}.heating"
    compliances = doc.of_type(AxialCompliance.TYPE)
    if not compliances:
        raise LookupError("the model has no AxialCompliance (screw) to grow thermally")
    axial = compliances[0]
    geometry = doc.component(axial)["params"]
    params = {"alpha": float(alpha), "heating": float(heating), "tau": float(tau)}
    params.update({k: geometry[k] for k in GEOMETRY})
    connect = [["{name}.a", f"{axial}.a"], ["{name}.b", f"{axial}.b"]]
    doc, name = doc.with_component("thermal", ThermalGrowth.TYPE, params, connect)
    return doc, f"{name}.heating"


def _thermal_edit(doc: Document, cand: Weights) -> Edit:
    # heating [K/m] from the signature's weight on x*D (residual = twin - measured
    # = -alpha * heating * D * (x_0 + x))
    heating = max(-cand.coefficients.get("x_D", 0.0) / ALPHA_STEEL, 1e-3)
    doc, slot = with_thermal_growth(doc, heating)
    own = [FreeParameter(name=slot, initial=heating, scale=heating, lower=0.0)]
    return make_edit(doc, own, {"heating_K_m": lambda v: v[slot]}, interacts=False)


def _thermal_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return with_thermal_growth(doc, p["heating_K_m"])[0]


def _travelled(m: Motion) -> dict[str, FloatArray]:
    # a screw still far from thermal equilibrium warms in proportion to the distance travelled
    # D(t); its heated length from the fixed bearing is x_0 + x with x_0 unknown here, so the
    # elongation alpha dT (x_0 + x) is a combination of D x and D
    dt = np.diff(m.t_s, prepend=m.t_s[0])
    travelled = np.cumsum(np.abs(m.v_m_s) * dt)
    return {"x_D": m.x_m * travelled, "D": travelled}


@dataclass(frozen=True, kw_only=True)
class ThermalGrowth(Component):
    TYPE = "ThermalGrowth"
    PORTS = {"a": "translational", "b": "translational"}
    COMPUTED_SLOTS = AxialCompliance.COMPUTED_SLOTS
    EFFECTS = (
        Effect(
            name="thermal_drift",
            domain="position",
            words="a position error that grows slowly with the distance travelled and with the "
            "distance from the fixed bearing: the screw heats up and lengthens",
            parameters="heating",
            signature=_travelled,
            edit=_thermal_edit,
            truth=_thermal_truth,
        ),
    )

    alpha: float  # thermal expansion coefficient of the screw [1/K]
    heating: float  # temperature rise per metre travelled, cold screw [K/m]
    tau: float  # thermal time constant of the screw [s]
    # geometry of the AxialCompliance this element accompanies (its stiffness k(x))
    arrangement: Literal["fixed-fixed", "fixed-free"]
    E: float  # [Pa]
    d_root: float  # [m]
    L: float  # [m]
    x_0: float  # nut distance from the fixed bearing when s_b = 0 [m]
    x_min: float  # [m]
    k_bearing: float  # [N/m]
    k_nut: float  # [N/m]

    def __post_init__(self) -> None:
        require_nonnegative("alpha", self.alpha)
        require_nonnegative("heating", self.heating)
        require_positive("tau", self.tau)
        if self.arrangement not in ("fixed-fixed", "fixed-free"):
            raise ValueError(
                f"arrangement = {self.arrangement!r}: must be 'fixed-fixed' or 'fixed-free'"
            )
        self._compliance()  # validates the geometry with the compliance's own messages

    def _compliance(self) -> AxialCompliance:
        return AxialCompliance(
            arrangement=self.arrangement,
            E=self.E,
            d_root=self.d_root,
            L=self.L,
            x_0=self.x_0,
            x_min=self.x_min,
            k_bearing=self.k_bearing,
            k_nut=self.k_nut,
            d=0.0,
        )

    def slots(self) -> dict[str, float]:
        geometry = self._compliance().slots()
        own = {"alpha": self.alpha, "heating": self.heating, "tau": self.tau}
        return own | {k: geometry[k] for k in STIFFNESS_SLOTS}

    def states(self) -> tuple[StateSpec, ...]:
        return (StateSpec(name="dT", unit="K", limit=TEMPERATURE_LIMIT_K),)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        s_a, v_a = g.across("a")
        s_b, v_b = g.across("b")
        dT, rate = g.x("dT"), g.local("rate")
        g.call(
            (rate,),
            "feed_twin.plant.thermal_growth.temperature_rate",
            (dT, v_a, g.p("heating"), g.p("tau")),
        )
        g.d("dT", rate)
        e, k, dk = g.local("e"), g.local("k"), g.local("dk")
        g.call(
            (e,),
            "feed_twin.plant.thermal_growth.elongation",
            (dT, f"{g.p('x_0')} + {s_a}", g.p("alpha")),
        )
        stiffness_args = (
            *(g.p(n) for n in ("L", "EA", "k_bearing", "k_nut")),
            fixed_fixed_flag(self.arrangement),
            g.p("x_min"),
        )
        g.call(
            (k, dk),
            "feed_twin.plant.axial_compliance.axial_stiffness",
            (f"{g.p('x_0')} + {s_b}", *stiffness_args),
        )
        f = g.local("f")
        g.line(f"{f} = {k} * {e}")
        g.apply("a", f"-{f}")
        g.apply("b", f)
        g.aux("elongation", e)
        g.aux("temperature_rise", dT)
        g.aux("force", f)
        g.power("source", "thermal", f"{f} * ({v_b} - {v_a})")
