"""Our planner beside LinuxCNC's (real LinuxCNC 2.9, one run per program): the requirements.

Two corpus programs (corners of 20-160 degrees; arcs and a full circle in G19) run on LinuxCNC
and through feed_twin.gcode with the same limits. Ours must keep arcs within chord_tolerance_m
and corners within G64 P, and the trapezoidal plan must take LinuxCNC's time to 5 %. LinuxCNC's
own corners are checked against what its motion module does to them: the joint commands are a
cubic B-spline through the planner's points, x_k -> (x_k-1 + 4 x_k + x_k+1)/6, which moves a
point on a curve inwards by a_n T^2/6, so its corners land up to a_max T^2/6 beyond P.
About 15 s (LinuxCNC start-up and shutdown included).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from feed_twin.gcode import SampledTrajectory, plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.metrics import CORNER_RESOLUTION
from feed_twin.gcode.peer import JERK_TIME_LIMIT, TIME_TOLERANCE, measure_side, time_ratio
from feed_twin.linuxcnc.machine import machine_for_config
from feed_twin.linuxcnc.runner import run_program

REPO = Path(__file__).resolve().parents[1]
CORPUS = REPO / "tests" / "fixtures" / "gcode" / "peer"
NC, SERVO = machine_for_config(REPO / "config" / "axis_default.yaml")


def linuxcnc_trajectory(program: Path) -> SampledTrajectory:
    result = run_program(program, nc=NC, servo=SERVO, say=lambda text: None)
    assert result.trace.samples_lost == 0 and result.overruns == 0
    trace = result.trace.cut(result.trace.program_span())
    return trace.commanded_trajectory(NC.axis_names)


@pytest.mark.parametrize("name", ["star.ngc", "arcs_g19.ngc"])
def test_our_planner_meets_the_requirements_beside_linuxcnc(name):
    program = CORPUS / name
    segments = programmed_path(program, NC)
    chord = NC.chord_tolerance_m

    def side(label, traj):
        return measure_side(label, traj, segments, chord_tolerance_m=chord)

    linuxcnc = side("linuxcnc", linuxcnc_trajectory(program))
    jerk = side("jerk", plan_program(program, NC))
    trapezoid = side(
        "trapezoid", plan_program(program, dataclasses.replace(NC, profile="trapezoid"))
    )
    assert jerk.failures == () and trapezoid.failures == ()
    trapezoid_ratio, jerk_ratio = time_ratio(trapezoid, linuxcnc), time_ratio(jerk, linuxcnc)
    assert trapezoid_ratio is not None and jerk_ratio is not None, "three sides accept it"
    assert abs(trapezoid_ratio - 1.0) <= TIME_TOLERANCE
    # The jerk limit costs time the same planner without it (acceleration-limited, as LinuxCNC)
    # does not spend; at the jerk the axis's first mode allows (T = 9 ms) that is less than
    # what LinuxCNC's half acceleration on arcs costs it (arcs_g19: 0.984x), and within the
    # 1.10x issue 30 asks.
    assert trapezoid_ratio < jerk_ratio <= JERK_TIME_LIMIT

    f = linuxcnc.figures
    assert f is not None and jerk.figures is not None, "both sides accept the program"
    T = SERVO.servo_period_s
    a_max = max(a.a_max_m_s2 for a in NC.axes)
    assert len(f.corners) == len(jerk.figures.corners) > 0
    assert f.arc_dev_max_m <= chord
    for corner, dev in zip(f.corners, f.corner_dev_m, strict=True):
        bound = corner.tolerance_m * (1 + CORNER_RESOLUTION) + a_max * T**2 / 6
        assert dev <= bound, f"LinuxCNC corner at line {corner.line}: {dev * 1e6:.3f} um"
    # Its straight moves are exact: the path stays within P of the programmed path (a blend's
    # middle is nearer to the two moves than to the corner point).
    assert f.path_dev_max_m <= NC.path_tolerance_m
