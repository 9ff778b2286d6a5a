"""Axis limits held on every program of the peer corpus, read from the sampled positions.

The planner's own velocities and accelerations are not used: peak velocity, acceleration and
jerk per axis come from first, second and third differences of the positions at t = k*T, as
`benchmarks/linuxcnc_peer.py` measures every side (by the mean value theorem a difference
quotient never exceeds the derivative's bound). The jerk profile must hold v, a and j; the
trapezoid v and a (it has no jerk limit).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import load_nc_config, plan_program

ROOT = Path(__file__).resolve().parent.parent
CONFIG = load_nc_config(ROOT / "config" / "axis_default.yaml")
CORPUS = sorted((ROOT / "tests" / "fixtures" / "gcode" / "peer").glob("*.ngc"))
SLACK = 1e-6  # relative: differences of positions at rounding level


def _peaks(pos: np.ndarray, period: float) -> list[np.ndarray]:
    return [np.max(np.abs(np.diff(pos, n=k, axis=0)), axis=0) / period**k for k in (1, 2, 3)]


@pytest.mark.parametrize("program", CORPUS, ids=[p.stem for p in CORPUS])
@pytest.mark.parametrize("profile", ["jerk", "trapezoid"])
def test_every_axis_stays_within_its_limits_on_the_corpus(program, profile):
    config = dataclasses.replace(CONFIG, profile=profile)
    traj = plan_program(program, config)
    v, a, j = _peaks(traj.pos_m, config.interpolation_period_s)
    v_top = np.maximum(config.v_max, config.rapid)
    assert np.all(v <= v_top * (1 + SLACK)), (v, v_top)
    assert np.all(a <= np.array(config.a_max) * (1 + SLACK)), (a, config.a_max)
    if profile == "jerk":
        assert np.all(j <= np.array(config.j_max) * (1 + SLACK)), (j, config.j_max)
    # A stop only where the program asks for one: the path ends at rest, and it moved.
    assert np.all(traj.vel_m_s[-1] == 0.0) and np.max(v) > 0.0
