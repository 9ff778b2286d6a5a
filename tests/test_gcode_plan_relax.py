"""The chains' limits at what the plan does (plan_relax): closed forms of the acceleration the
curvature terms leave, and a raster's row ends planned faster within every axis limit."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from gcode_random import sampled_limit_ratios

from feed_twin.gcode import load_nc_config, plan_program, plan_relax
from feed_twin.gcode.plan_chains import ChainTerms, chain_acceleration
from feed_twin.gcode.plan_limits import AxisLimits

ROOT = Path(__file__).resolve().parent.parent
CONFIG = load_nc_config(ROOT / "config" / "axis_default.yaml")
# The jerk limits the default had before the axis's first mode set them (T = 50 ms, not 9):
# a window spans 3.3 mm at 66.7 mm/s, so the bounds erode a chain's caps far ahead of its end.
WIDE_WINDOW = dataclasses.replace(
    CONFIG,
    axes=tuple(
        dataclasses.replace(axis, j_max_m_s3=axis.a_max_m_s2 / 0.05) for axis in CONFIG.axes
    ),
)


def _terms(a_g: float, j_g: float, n: int = 1) -> ChainTerms:
    """One body along X with curvature a_g [1/m] and its change j_g [1/m^2] on X."""
    axis = np.zeros((n, 3))
    return ChainTerms(
        a_g=axis + [a_g, 0.0, 0.0], j_g=axis + [j_g, 0.0, 0.0], k_g=axis.copy(),
        u_g=axis + [1.0, 0.0, 0.0],
    )  # fmt: skip


def test_a_straight_chain_gets_twice_the_acceleration_where_s_keeps_one_sign():
    limits = AxisLimits.of(CONFIG)
    T, j, a = limits.window_s, limits.j_max[0], limits.a_max[0]
    both = chain_acceleration(_terms(0.0, 0.0), np.array([0.05]), limits)
    one = chain_acceleration(_terms(0.0, 0.0), np.array([0.05]), limits, one_sign=np.array([True]))
    # |s'''| <= 2 A / T within j: A = j T / 2 = 1.5; one sign, A / T: j T = 3 = a_max.
    assert both[0] == pytest.approx(j * T / 2.0, rel=1e-12)
    assert one[0] == pytest.approx(min(j * T, a), rel=1e-12)


def test_the_curvature_terms_leave_more_acceleration_at_a_lower_speed():
    # 2 A / T + 3 a_g v A + j_g v^3 <= j (and a_g v^2 + A <= a): A falls with v.
    limits = AxisLimits.of(CONFIG)
    T, j = limits.window_s, limits.j_max[0]
    a_g, j_g = 2000.0, 1e6  # a blend of R = 0.5 mm whose curvature ramps over 2 mm
    v = np.array([0.002, 0.01, 0.03])
    got = chain_acceleration(_terms(a_g, j_g, 3), v, limits)
    want = np.minimum((j - j_g * v**3) / (2.0 / T + 3.0 * a_g * v), limits.a_max[0] - a_g * v * v)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert got[0] > got[1] > got[2] > 0.0


def _raster(rows: int, steps: int) -> str:
    """A CAM finishing raster: rows of 0.2 mm moves over a curved surface, 0.5 mm apart."""
    lines = ["G21 G90 G17 G64 P0.01", "G0 X0 Y0 Z1", "G1 Z0 F1200", "F4000"]
    for row in range(rows):
        y = 0.5 * row
        xs = range(steps + 1) if row % 2 == 0 else range(steps, -1, -1)
        for k in xs:
            x = 0.2 * k
            z = 0.5 * math.sin(x / 6.0 + y / 4.0)
            lines.append(f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("config", "least_gain_s"),
    [
        # Each of the 3 row ends brakes and starts at up to twice the acceleration, its caps
        # no longer lowered 2 mm ahead: tens of milliseconds each.
        (WIDE_WINDOW, 3 * 0.02),
        # T = 9 ms erodes 0.3 mm only: less to win (about 16 ms a row end), still faster.
        (CONFIG, 0.0),
    ],
    ids=["T50ms", "default"],
)
def test_a_raster_row_end_runs_faster_with_the_limits_at_the_planned_speeds(
    monkeypatch, config, least_gain_s
):
    program = _raster(rows=4, steps=60)
    relaxed = plan_program(program, config)
    monkeypatch.setattr(plan_relax, "RELAX_STEPS", 0)  # the bounds alone
    bounded = plan_program(program, config)
    gain = bounded.t_s[-1] - relaxed.t_s[-1]
    assert gain > least_gain_s, (bounded.t_s[-1], relaxed.t_s[-1])
    # Every axis within v, a and j from differences of the sampled positions.
    assert max(sampled_limit_ratios(relaxed, config)) <= 1.0
    np.testing.assert_allclose(relaxed.pos_m[-1], bounded.pos_m[-1], atol=1e-12)
