"""A G-code program as the engine's per-tick setpoints, for the runs that compare backends."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feed_twin.core.config import load_yaml
from feed_twin.gcode.config import nc_config_from_mapping
from feed_twin.gcode.planner import plan_program
from feed_twin.sim.program import nc_reference

DEFAULT_NC = Path(__file__).resolve().parents[2] / "config" / "axis_default.yaml"


def program_ref(program: Path, base_period_s: float, nc_config: Path = DEFAULT_NC) -> np.ndarray:
    """(n, REF_SIZE): the program's twin-axis setpoints planned with the nc: section of
    `nc_config`, each NC sample held for the base ticks of its period."""
    nc = load_yaml(nc_config)["nc"]
    cfg = nc_config_from_mapping(nc, source=str(nc_config))
    traj = plan_program(program, cfg)
    x, v, a = traj.axis(cfg.twin_axis)
    dec = round((traj.t_s[1] - traj.t_s[0]) / base_period_s)
    return nc_reference(x, v, a, dec)
