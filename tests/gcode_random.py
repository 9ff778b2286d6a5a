"""Random G-code programs for the planner's stress tests, and the axis limits checked from the
sampled positions (tests/test_gcode_planner.py, benchmarks/lookahead_limits.py)."""

from __future__ import annotations

import numpy as np

from feed_twin.gcode import NcConfig, SampledTrajectory
from feed_twin.gcode.metrics import LIMIT_SLACK


def random_program(rng: np.random.Generator, n: int) -> str:
    """Lines, arcs, rapids, dwells, mode switches and bursts of tiny moves, within travel."""
    lines = [f"G21 G90 G64 P{rng.uniform(0.001, 0.5):.3f}"]
    for _ in range(n):
        r = rng.random()
        x, y, z = rng.uniform(-80, 80, 3)
        f = rng.uniform(100, 12000)
        if r < 0.1:
            lines.append(f"G0 X{x:.3f} Y{y:.3f} Z{z / 4:.3f}")
        elif r < 0.2:
            lines.append(f"G3 X{x:.3f} Y{y:.3f} R{rng.uniform(90, 150):.3f} F{f:.0f}")
        elif r < 0.25:
            lines.append(f"G4 P{rng.uniform(0, 0.05):.3f}")
        elif r < 0.3:
            lines.append("G61" if rng.random() < 0.5 else "G64")
        elif r < 0.5:
            lines.append(f"G1 X{x:.3f} F{f:.0f}")
        elif r < 0.7:
            dx, dy = rng.normal(0, 0.2, 2)
            lines.append(f"G91 G1 X{dx:.4f} Y{dy:.4f} F{f:.0f}\nG90")
        else:
            lines.append(f"G1 X{x:.3f} Y{y:.3f} Z{z / 4:.3f} F{f:.0f}")
    return "\n".join(lines + ["M2"])


ROUNDING_M = 1e-12  # [m] positions differ by this much where the raw plan's pieces meet


def sampled_limit_ratios(traj: SampledTrajectory, config: NcConfig) -> tuple[float, float, float]:
    """Worst peak |v|, |a|, |j| over every axis from differences of the sampled positions,
    each as a share of its limit: with LIMIT_SLACK of it (the plan reaches a limit to rounding)
    and the 2^n ROUNDING_M the n-th difference of positions may carry."""
    period = config.interpolation_period_s
    v_max = np.maximum(config.v_max, config.rapid)
    limits = (v_max, np.array(config.a_max), np.array(config.j_max))
    ratios = []
    for order, limit in enumerate(limits, start=1):
        peak = np.max(np.abs(np.diff(traj.pos_m, order, axis=0)), axis=0) / period**order
        ratios.append(
            float(
                np.max(peak / (limit * (1.0 + LIMIT_SLACK) + 2**order * ROUNDING_M / period**order))
            )
        )
    return ratios[0], ratios[1], ratios[2]
