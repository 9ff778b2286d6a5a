"""Helpers of the C-backend tests: a G-code program as the engine's per-tick setpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feed_twin.control import signals
from feed_twin.gcode.config import nc_config_from_mapping
from feed_twin.gcode.planner import plan_program
from feed_twin.io.config import load_yaml

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "tests" / "fixtures" / "gcode" / "sample.ngc"


def program_ref(program: Path, base_period_s: float) -> np.ndarray:
    """(n, REF_SIZE): the program's X setpoints planned with config/axis_default.yaml's nc:
    section, each NC sample held for its base ticks."""
    nc = load_yaml(ROOT / "config" / "axis_default.yaml")["nc"]
    cfg = nc_config_from_mapping(nc, source="config/axis_default.yaml")
    traj = plan_program(program, cfg)
    x, v, a = traj.axis(cfg.twin_axis)
    dec = round((traj.t_s[1] - traj.t_s[0]) / base_period_s)
    ref = np.zeros((len(x) * dec, signals.REF_SIZE))
    ref[:, signals.REF_POS_M] = np.repeat(x, dec)
    ref[:, signals.REF_VEL_M_S] = np.repeat(v, dec)
    ref[:, signals.REF_ACC_M_S2] = np.repeat(a, dec)
    return ref
