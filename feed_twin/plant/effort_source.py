"""Ideal force or torque source behind a first-order current loop.

For drives where only the force command is known (the EMPS bench: force = gtau * vir): the
commanded effort f_cmd = gain * effort_cmd (0 while the drive is disabled) is reached through
    T_lag * df/dt = f_cmd - f     (T_lag > 0; the closed current loop as a first-order lag),
or f = f_cmd at once when T_lag = 0. The source delivers f*v into the axis.
Port: `flange` (rotational [rad, rad/s, N m] or translational [m, m/s, N], set by `domain`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, PortKind, StateSpec


@dataclass(frozen=True, kw_only=True)
class EffortSource(Component):
    TYPE = "EffortSource"
    PORTS = {}

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

    def structure(self) -> tuple:
        return (self.domain, self.T_lag > 0.0)

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
