"""thermal_drift in a model document: the ThermalGrowth component next to the axial compliance.

`with_thermal_growth` adds a feed_twin.plant.thermal_growth.ThermalGrowth in parallel with the
model's (first) AxialCompliance, with that compliance's geometry, so the pair acts as one
spring stretched by the screw's thermal elongation. The same function builds the truth of the
synthetic runs and the workflow's edit, so both use one description of the effect.

Only the heating rate [K/m] is fitted. A record much shorter than the thermal time constant
(minutes to an hour) sees dT grow in proportion to the distance travelled, heating * D(t): the
time constant is not identifiable from it and stays at its documented default.
"""

from __future__ import annotations

from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.twin import ModelDoc
from feed_twin.plant.thermal_growth import ALPHA_STEEL

TAU_DEFAULT_S = 1800.0  # [s] thermal time constant of a ball screw (tens of minutes)
GEOMETRY = ("arrangement", "E", "d_root", "L", "x_0", "x_min", "k_bearing", "k_nut")


def with_thermal_growth(
    doc: ModelDoc, heating: float, *, tau: float = TAU_DEFAULT_S, alpha: float = ALPHA_STEEL
) -> tuple[ModelDoc, str]:
    """The document with thermal growth of the screw (or its heating set); (doc, heating slot)."""
    existing = doc.of_type("ThermalGrowth")
    if existing:
        return doc.set(f"{existing[0]}.heating", heating), f"{existing[0]}.heating"
    compliances = doc.of_type("AxialCompliance")
    if not compliances:
        raise LookupError("the model has no AxialCompliance (screw) to grow thermally")
    axial = compliances[0]
    geometry = doc.component(axial)["params"]
    name = doc._free_name("thermal")
    params = {"alpha": float(alpha), "heating": float(heating), "tau": float(tau)}
    params.update({k: geometry[k] for k in GEOMETRY})
    new = doc.set_raw(axial, "arrangement", geometry["arrangement"])  # a private copy
    new.data["plant"]["components"].append(
        {"name": name, "type": "ThermalGrowth", "params": params}
    )
    new.data["plant"]["connect"].extend([[f"{name}.a", f"{axial}.a"], [f"{name}.b", f"{axial}.b"]])
    return new, f"{name}.heating"


def initial_heating(cand: Candidate, alpha: float = ALPHA_STEEL) -> float:
    """Heating [K/m] from the signature's weight on x*D (see effects: residual = twin - measured
    = -alpha * heating * D * (x_0 + x))."""
    return max(-cand.coefficients.get("x_D", 0.0) / alpha, 1e-3)
