"""The floor of the jerk profile's time: closed forms of jerk-limited speed changes, and the
floor of a planned program against the jerk profile's own time."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.jerk_floor import change_time, jerk_floor_extra, near_stops, stretch_time
from feed_twin.gcode.metrics import trajectory_figures
from feed_twin.linuxcnc.machine import machine_for_config

REPO = Path(__file__).resolve().parents[1]
NC, _ = machine_for_config(REPO / "config" / "axis_default.yaml")
A, J = 3.0, 60.0  # [m/s^2], [m/s^3]: T = A / J = 50 ms
INF = np.array([np.inf])


def one(value: float) -> np.ndarray:
    return np.array([value])


def test_a_speed_change_takes_the_s_curve_time():
    # A full change reaches A: dv / A + A / J; a short one does not: 2 sqrt(dv / J).
    assert change_time(one(0.3), one(A), one(J))[0] == pytest.approx(0.3 / A + A / J)
    assert change_time(one(0.1), one(A), one(J))[0] == pytest.approx(2.0 * math.sqrt(0.1 / J))
    # Continuous where the two meet (dv = A^2 / J), and dv / A without a jerk limit.
    edge = A * A / J
    below = change_time(one(edge * (1 - 1e-9)), one(A), one(J))[0]
    assert below == pytest.approx(change_time(one(edge), one(A), one(J))[0], rel=1e-6)
    assert change_time(one(0.1), one(A), INF)[0] == pytest.approx(0.1 / A)


def test_a_stretch_costs_the_closed_form_of_a_jerk_limited_stop_and_go():
    D, V = one(0.2), one(0.25)  # rest to rest, long enough to cruise at V
    t_jerk = stretch_time(D, one(0.0), one(0.0), V, one(A), one(J))[0]
    t_acc = stretch_time(D, one(0.0), one(0.0), V, one(A), INF)[0]
    assert t_acc == pytest.approx(0.2 / 0.25 + 0.25 / A)
    assert t_jerk - t_acc == pytest.approx(A / J)  # T per full stop-and-go
    # From a cruise at F < A^2 / J to rest: sqrt(F / J) - F / (2 A) more (half a stop-and-go).
    F = 0.1
    t_jerk = stretch_time(D, one(F), one(0.0), one(F), one(A), one(J))[0]
    t_acc = stretch_time(D, one(F), one(0.0), one(F), one(A), INF)[0]
    assert t_jerk - t_acc == pytest.approx(math.sqrt(F / J) - F / (2.0 * A))
    # Too short to reach V: the peak is where both S-curves fill the length exactly.
    short = one(1e-3)
    t = stretch_time(short, one(0.0), one(0.0), V, one(A), one(J))[0]
    vp = (0.5 * t) ** 2 * J / 4.0  # each half a short change: t / 2 = 2 sqrt(vp / J)
    assert vp * t / 2.0 == pytest.approx(1e-3, rel=1e-9)  # covered at the mean speed vp / 2


def test_near_stops_are_the_deep_minima_and_the_ends():
    up = np.linspace(0.0, 1.0, 50)
    profile = np.concatenate((up, 1.0 - 0.6 * up, 0.4 + 0.6 * up, 1.0 - 0.3 * up, 0.7 + 0.3 * up))
    profile = np.concatenate((profile, up[::-1]))
    stops = near_stops(profile)
    # The dip to 0.4 (below half the peaks around it) is one; the dip to 0.7 is not.
    assert len(stops) == 3
    assert stops[0] == 0 and stops[-1] == len(profile) - 1
    assert profile[stops[1]] == pytest.approx(0.4)


@pytest.mark.parametrize("moves", ["G1 X100 F12000", "G1 X100 F12000\nY50\nX60\nY0"])
def test_the_jerk_profile_meets_the_floor_on_straight_moves_between_stops(moves):
    # Exact stops (G61) between straight moves: each stretch is one stop-and-go, which the
    # filtered plan runs in T more than the trapezoid: the floor, to a few periods.
    program = f"G21 G90 G54 G61\n{moves}\nM2\n"
    trapezoid = plan_program(program, dataclasses.replace(NC, profile="trapezoid"))
    jerk = plan_program(program, NC)
    segments = programmed_path(program, NC)
    t_trapezoid = trajectory_figures(trapezoid, segments).program_time_s
    t_jerk = trajectory_figures(jerk, segments).program_time_s
    extra, stops = jerk_floor_extra(trapezoid, np.array(NC.a_max), np.array(NC.j_max))
    assert stops == moves.count("\n")
    T = NC.axes[0].a_max_m_s2 / NC.axes[0].j_max_m_s3
    assert extra == pytest.approx(T * (stops + 1), rel=0.02)
    assert t_jerk == pytest.approx(t_trapezoid + extra, abs=(stops + 2) * 3e-3)
