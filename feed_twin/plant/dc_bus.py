"""DC bus: a stiff source behind an internal resistance (rectifier + DC-link as seen by the drive).

Equation: u_dc = u_0 - R_i * i_dc, where i_dc is the current the inverter draws. The source
delivers u_0*i_dc, the resistance dissipates R_i*i_dc^2. The bus voltage is also what the drive
measures (MEAS_U_DC_V), without delay.
Port: `dc` (dc: u [V] set here, i [A] drawn by the load).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter


@dataclass(frozen=True, kw_only=True)
class DcBus(Component):
    TYPE = "DcBus"
    PORTS = {"dc": "dc"}
    STATE_OUTPUTS = {"u_dc": "u_dc", "i_dc": "i_dc"}

    u_0: float  # open-circuit bus voltage [V]
    R_i: float  # internal resistance [ohm]

    def __post_init__(self) -> None:
        require_positive("u_0", self.u_0)
        require_nonnegative("R_i", self.R_i)

    def emit(self, stage: str, g: Emitter) -> None:
        u, i = g.el("dc", "u"), g.el("dc", "i")
        if stage == "dc_voltage":
            g.line(f"{u} = {g.p('u_0')} - {g.p('R_i')} * {i}")
            g.aux("u_dc", u)
            g.aux("i_dc", i)
            g.power("source", "supply", f"{g.p('u_0')} * {i}")
            g.power("loss", "resistance", f"{g.p('R_i')} * {i} * {i}")
        elif stage == "sense":
            g.meas("MEAS_U_DC_V", u, delay="0")
