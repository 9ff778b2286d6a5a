"""Plausibility ranges of physical parameters: a typo of a few orders of magnitude is an error.

The components' own checks reject what is impossible (a negative mass); these ranges reject
what no feed axis has (a table of 1e300 kg or 1e-30 kg), which otherwise compiles and runs into
overflow or a stiff system. A machine that really lies outside a range lists the parameter under
`plant.unusual` (e.g. `unusual: [table.m]`), which skips its check.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from feed_twin.core.config import ConfigError
from feed_twin.plant.component import Component

# (component type, field) -> (low, high) of |value| in SI units; 0 always passes (effects off).
RANGES: dict[tuple[str, str], tuple[float, float]] = {
    ("Mass", "m"): (1e-3, 1e5),  # [kg] a slide of grams to a gantry of 100 t
    ("Inertia", "J"): (1e-9, 10.0),  # [kg m^2]
    ("Pmsm", "J"): (1e-8, 10.0),  # [kg m^2]
    ("Pmsm", "R_s"): (1e-3, 100.0),  # [ohm]
    ("Pmsm", "L_d"): (1e-6, 1.0),  # [H]
    ("Pmsm", "L_q"): (1e-6, 1.0),  # [H]
    ("Pmsm", "psi_pm"): (1e-3, 10.0),  # [V s]
    ("Pmsm", "p"): (1.0, 50.0),  # pole pairs
    ("DcBus", "u_0"): (1.0, 2000.0),  # [V]
    ("BallScrew", "lead"): (1e-4, 0.1),  # [m/rev]
    ("Coupling", "k"): (1.0, 1e9),  # [N m/rad]
    ("GuideFriction", "F_c_pos"): (0.0, 1e5),  # [N]
    ("GuideFriction", "F_c_neg"): (0.0, 1e5),  # [N]
    ("GuideFriction", "F_v_pos"): (0.0, 1e6),  # [N s/m]
    ("GuideFriction", "F_v_neg"): (0.0, 1e6),  # [N s/m]
}
# Any other number of a component: beyond this magnitude it is a typo, not a machine.
ANY_NUMBER_MAX = 1e15


def check_plausible(
    components: Mapping[str, Component], unusual: Iterable[str], source: str
) -> None:
    """Raise ConfigError naming the first parameter outside its range (unless listed unusual)."""
    skip = set(unusual)
    unknown = sorted(n for n in skip if n.split(".")[0] not in components)
    if unknown:
        raise ConfigError(
            f"{source}: plant.unusual: {', '.join(unknown)}: no such component parameter"
        )
    for name, comp in components.items():
        for field, value in vars(comp).items():
            key = f"{name}.{field}"
            if key in skip or isinstance(value, bool) or not isinstance(value, int | float):
                continue
            low, high = RANGES.get((comp.TYPE, field), (0.0, ANY_NUMBER_MAX))
            size = abs(value)
            if size == 0.0 or not math.isfinite(size) or low <= size <= high:
                continue
            raise ConfigError(
                f"{source}: plant.{key} = {value!r}: implausible for a feed axis (expected "
                f"|value| in [{low:g}, {high:g}]); list it under plant.unusual if the machine "
                "really has it"
            )
