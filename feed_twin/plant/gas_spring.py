"""A gas spring holding up a vertical slide (counterbalance), with its catalogue's linear rate.

Equation: f = f_0 - k * (s - s_0) into the flange: f_0 [N] at the slide position s_0 [m], rising
by k [N/m] as the slide goes down and compresses the gas. Gas-spring catalogues give the force
at two points of the stroke (the progression); over a slide's stroke the polytropic law
p V^n = const bends that line by a few per cent, which the rate k between the two points
keeps. Potential energy -f_0 (s - s_0) + k (s - s_0)^2 / 2.
Port: `flange` (translational: s [m], v [m/s], f [N]).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter


@dataclass(frozen=True, kw_only=True)
class GasSpring(Component):
    TYPE = "GasSpring"
    PORTS = {"flange": "translational"}

    f_0: float  # force into the flange at s = s_0 [N]
    s_0: float  # slide position of f_0 [m]
    k: float  # force rise per metre of travel towards negative s [N/m]

    def __post_init__(self) -> None:
        require_positive("f_0", self.f_0)
        require_finite("s_0", self.s_0)
        require_nonnegative("k", self.k)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "dynamics":
            return
        s, _ = g.across("flange")
        ds = g.local("ds")
        g.line(f"{ds} = {s} - {g.p('s_0')}")
        f = f"({g.p('f_0')} - {g.p('k')} * {ds})"
        g.apply("flange", f)
        g.aux("force", f)
        g.stored("gas", f"-{g.p('f_0')} * {ds} + 0.5 * {g.p('k')} * {ds} * {ds}")
