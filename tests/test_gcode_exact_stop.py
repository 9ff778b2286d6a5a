"""Exact stop (G60, G61, G9) and the settle time after it, against closed-form program times."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.gcode.interpreter import Interpreter
from feed_twin.gcode.items import Move
from feed_twin.gcode.planner import iter_blocks

FIXTURES = Path(__file__).parent / "fixtures" / "gcode"
CONFIG = load_nc_config(FIXTURES / "nc_test.yaml")
SETTLE_S = 0.065  # [s] about what a Sinumerik machining centre waits per block
TRAPEZOID = dataclasses.replace(CONFIG, profile="trapezoid", exact_stop_settle_s=SETTLE_S)
MM = 1e-3
A_X = CONFIG.axes[0].a_max_m_s2  # [m/s^2]; every test move is X alone, below X's v_max


def trapezoid_time(length_m: float, v: float, a: float) -> float:
    """Rest-to-rest time of a trapezoidal profile that reaches v."""
    assert length_m >= v * v / a
    return length_m / v + v / a


def block_ends(program: str) -> list[tuple[int, float, bool]]:
    """(line, X end [m], exact stop) of each move the interpreter makes."""
    _, blocks = iter_blocks(program, CONFIG)
    moves = [i for i in Interpreter(CONFIG, file="<text>").run(blocks) if isinstance(i, Move)]
    return [(m.line, m.end_m[0], m.exact_stop) for m in moves]


def assert_holds(traj, holds: list[tuple[float, int, float]]) -> None:
    """Each (start time, line, X) hold: at rest on that line at that point for SETTLE_S."""
    for t0, line, x in holds:
        inside = (traj.t_s > t0 + 1e-9) & (traj.t_s < t0 + SETTLE_S - 1e-9)
        assert np.count_nonzero(inside) >= round(SETTLE_S / CONFIG.interpolation_period_s) - 1
        assert np.all(traj.vel_m_s[inside] == 0.0)
        assert np.all(traj.acc_m_s2[inside] == 0.0)
        assert np.all(traj.line[inside] == line)
        np.testing.assert_allclose(traj.pos_m[inside, 0], x, rtol=0, atol=1e-12)
        # the move into the hold ends at rest: the sample before it is slower than a*T
        before = np.flatnonzero(traj.t_s <= t0)[-1]
        assert abs(traj.vel_m_s[before, 0]) <= A_X * CONFIG.interpolation_period_s * (1 + 1e-9)


def test_g61_stops_every_block_and_holds_for_the_settle_time():
    # back and forth along X at different feeds: every block is its own trapezoid
    program = "G61 G1 X100 F6000\nX40 F3000\nX70\nX130 F9000\nM2"
    feeds = [0.1, 0.05, 0.05, 0.15]  # [m/s]
    ends = block_ends(program)
    assert [stop for _, _, stop in ends] == [True] * 4
    traj = plan_program(program, TRAPEZOID)
    t, x0, holds = 0.0, 0.0, []
    for (line, x, _), v in zip(ends, feeds, strict=True):
        t += trapezoid_time(abs(x - x0), v, A_X)
        holds.append((t, line, x))
        t += SETTLE_S
        x0 = x
    end = [e for e in traj.events if e.kind == "end"][0]
    # the sum of the trapezoids plus one settle time per exact stop
    assert end.t_s == pytest.approx(t, rel=1e-9)
    assert end.t_s == pytest.approx(3.375 + 4 * SETTLE_S, rel=1e-9)
    assert_holds(traj, holds)


def test_g60_is_the_same_exact_stop_as_g61():
    g61 = plan_program("G61 G1 X100 F6000\nX40 F3000\nX70\nM2", TRAPEZOID)
    g60 = plan_program("G60 G1 X100 F6000\nX40 F3000\nX70\nM2", TRAPEZOID)
    np.testing.assert_array_equal(g60.pos_m, g61.pos_m)
    np.testing.assert_array_equal(g60.line, g61.line)
    assert g60.events == g61.events


def test_g9_stops_its_block_only():
    # collinear blocks at one feed: blended, they are one trapezoid; G9 splits them at X150
    blended = plan_program("G1 X100 F6000\nX150\nX200\nX250\nM2", TRAPEZOID)
    g9 = plan_program("G1 X100 F6000\nG9 X150\nX200\nX250\nM2", TRAPEZOID)
    assert [stop for _, _, stop in block_ends("G1 X100 F6000\nG9 X150\nX200\nX250")] == [
        False,
        True,
        False,
        False,
    ]
    t_blended = trapezoid_time(0.25, 0.1, A_X)
    t_g9 = trapezoid_time(0.15, 0.1, A_X) + SETTLE_S + trapezoid_time(0.1, 0.1, A_X)
    assert blended.events[-1].t_s == pytest.approx(t_blended, rel=1e-9)
    assert g9.events[-1].t_s == pytest.approx(t_g9, rel=1e-9)
    assert_holds(g9, [(trapezoid_time(0.15, 0.1, A_X), 2, 0.15)])
    # no other stop: the speed stays at F from the end of the hold's ramp to the last ramp
    cruise = (g9.t_s > t_g9 - 1.0 + 1e-9) & (g9.t_s < t_g9 - 0.05 - 1e-9)
    assert np.all(np.abs(g9.vel_m_s[cruise, 0] - 0.1) <= 1e-12)


def test_g64_restores_blending_and_the_program_gets_shorter():
    exact = "G61 G1 X100 F6000\nX150\nX200\nX250\nM2"
    mixed = "G61 G1 X100 F6000\nX150\nG64 X200\nX250\nM2"
    assert [stop for _, _, stop in block_ends(mixed)] == [True, True, False, False]
    t_exact = trapezoid_time(0.1, 0.1, A_X) + 3 * trapezoid_time(0.05, 0.1, A_X)
    t_mixed = trapezoid_time(0.1, 0.1, A_X) + trapezoid_time(0.05, 0.1, A_X)
    t_mixed += trapezoid_time(0.1, 0.1, A_X)  # X150 -> X250 blended into one
    a = plan_program(exact, TRAPEZOID)
    b = plan_program(mixed, TRAPEZOID)
    assert a.events[-1].t_s == pytest.approx(t_exact + 4 * SETTLE_S, rel=1e-9)
    assert b.events[-1].t_s == pytest.approx(t_mixed + 2 * SETTLE_S, rel=1e-9)
    assert b.events[-1].t_s < a.events[-1].t_s - 0.1


def test_settle_adds_its_time_per_exact_stop_on_jerk_limited_arcs():
    # G61 on arcs: one stop per block (at the end of the last chord), not one per chord
    program = "G61 G1 X20 F3000\nG3 X40 Y0 R10\nG2 X60 Y0 R10\nG1 Y20\nG4 P0.2\nX0\nM2"
    n_stops = sum(stop for _, _, stop in block_ends(program))
    assert n_stops == 5
    jerk = dataclasses.replace(CONFIG, exact_stop_settle_s=SETTLE_S)
    with_settle = plan_program(program, jerk)
    without = plan_program(program, dataclasses.replace(CONFIG, exact_stop_settle_s=0.0))
    difference = with_settle.events[-1].t_s - without.events[-1].t_s
    assert difference == pytest.approx(n_stops * SETTLE_S, abs=1e-9)
    # the dwell follows the settle of line 4: both at rest at X60 Y20
    dwell = [e for e in with_settle.events if e.kind == "dwell"][0]
    dwell_before = [e for e in without.events if e.kind == "dwell"][0]
    assert dwell.t_s - dwell_before.t_s == pytest.approx(4 * SETTLE_S, abs=1e-9)
    at_rest = (with_settle.t_s > dwell.t_s - SETTLE_S + 1e-9) & (with_settle.t_s < dwell.t_s + 0.2)
    assert np.all(with_settle.vel_m_s[at_rest] == 0.0)
    np.testing.assert_allclose(with_settle.pos_m[at_rest, :2], [[0.06, 0.02]] * at_rest.sum())


def test_programs_without_exact_stop_ignore_the_settle_time():
    program = "G1 X20 F3000\nG3 X40 Y0 R10\nG1 Y20\nG4 P0.2\nX0\nM2"
    a = plan_program(program, CONFIG)
    b = plan_program(program, dataclasses.replace(CONFIG, exact_stop_settle_s=0.5))
    np.testing.assert_array_equal(a.pos_m, b.pos_m)
    np.testing.assert_array_equal(a.vel_m_s, b.vel_m_s)
    assert a.events == b.events


def test_negative_settle_time_is_a_config_error():
    with pytest.raises(ValueError, match=r"^exact_stop_settle_s = -0.01: must be >= 0$"):
        dataclasses.replace(CONFIG, exact_stop_settle_s=-0.01)
    with pytest.raises(ValueError, match=r"^exact_stop_settle_s = nan: must be a finite number$"):
        dataclasses.replace(CONFIG, exact_stop_settle_s=math.nan)


@pytest.mark.parametrize("lookahead", [8, 400])
def test_settle_times_survive_the_look_ahead_windows(lookahead):
    # 40 exact stops: with 8 moves of look-ahead the holds fall on many committed chunks
    lines = ["G61 G1 F6000"] + [f"X{10 * (k % 2) + 10}" for k in range(40)] + ["M2"]
    config = dataclasses.replace(TRAPEZOID, lookahead_segments=lookahead)
    traj = plan_program("\n".join(lines), config)
    expected = 40 * (trapezoid_time(0.01, 0.1, A_X) + SETTLE_S)  # 10 mm back and forth
    assert traj.events[-1].t_s == pytest.approx(expected, rel=1e-9)
    held = np.flatnonzero(np.all(traj.vel_m_s == 0.0, axis=1))
    assert len(held) >= 40 * (round(SETTLE_S / CONFIG.interpolation_period_s) - 1)


def test_settle_time_equals_a_dwell_after_each_exact_stop_block():
    # two paths to the same motion: the config's settle, and a G4 written after every block
    program = "G61 G1 X20 F3000\nG3 X40 Y0 R10\nG1 Y15 F2000\nG0 X0 Y0\nM2"
    dwells = "G61 G1 X20 F3000\nG4 P0.065\nG3 X40 Y0 R10\nG4 P0.065\nG1 Y15 F2000\nG4 P0.065\n"
    dwells += "G0 X0 Y0\nG4 P0.065\nM2"
    settled = plan_program(program, dataclasses.replace(CONFIG, exact_stop_settle_s=SETTLE_S))
    written = plan_program(dwells, CONFIG)
    np.testing.assert_array_equal(settled.t_s, written.t_s)
    np.testing.assert_array_equal(settled.pos_m, written.pos_m)
    np.testing.assert_array_equal(settled.vel_m_s, written.vel_m_s)
    np.testing.assert_array_equal(settled.acc_m_s2, written.acc_m_s2)


def test_g60_and_g64_in_one_block_conflict():
    with pytest.raises(ValueError, match=r"^<text>:1:5: word 'G64': conflicts with G60 \(both in"):
        plan_program("G60 G64 G1 X1 F100\nM2", CONFIG)
