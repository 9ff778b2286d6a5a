"""CAM polylines smoothed within the tolerance, and where long chains are broken for look-ahead."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import SampledTrajectory, load_nc_config, plan_program, plan_program_stream
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.metrics import trajectory_figures
from feed_twin.gcode.plan_breaks import forced_breaks
from feed_twin.gcode.plan_smoothing import (
    SMOOTH_MOVE_M,
    SMOOTH_REACH,
    SMOOTH_SHARE,
    blend_tolerance,
    movable_vertices,
    smooth_vertices,
)

CONFIG = load_nc_config(Path(__file__).parent / "fixtures" / "gcode" / "nc_test.yaml")
UM = 1e-6


def _circle(radius: float, step: float, count: int, decimals: int) -> np.ndarray:
    """Points [m] every `step` [m] on a circle, rounded to `decimals` in mm as G-code is."""
    angle = np.arange(count) * step / radius
    points = radius * np.column_stack((np.cos(angle), np.sin(angle)))
    return np.round(points * 1e3, decimals) * 1e-3


def _turns(P: np.ndarray) -> np.ndarray:
    u = np.diff(P, axis=0)
    u /= np.linalg.norm(u, axis=1)[:, None]
    return np.linalg.norm(u[1:] - u[:-1], axis=1)


def test_smoothing_keeps_a_line_and_removes_the_rounding_of_a_circle():
    # Unevenly spaced points of a straight line: a quadratic through them is the line.
    t = np.cumsum(np.r_[0.0, np.linspace(1e-4, 2e-4, 30)])
    line = np.column_stack((t, 0.5 * t, -0.25 * t))
    inner = np.r_[False, np.ones(len(line) - 2, dtype=bool), False]
    limit = np.full(len(line), 1.0)
    np.testing.assert_allclose(smooth_vertices(line, inner, limit, SMOOTH_REACH), line, atol=1e-15)
    # A 5 mm circle in 0.15 mm moves, rounded to 0.1 um: the direction change per node
    # (0.03) varies by a few 1e-3 from the rounding. Smoothed, it varies far less, and the
    # points stay on the circle (the quadratic misses it by about t^4 / R^3, well below 0.1 um).
    circle = _circle(5e-3, 1.5e-4, 120, 4)
    inner = np.r_[False, np.ones(len(circle) - 2, dtype=bool), False]
    smooth = smooth_vertices(circle, inner, np.full(len(circle), 2.5 * UM), SMOOTH_REACH)
    middle = slice(SMOOTH_REACH, -SMOOTH_REACH)
    assert np.std(_turns(smooth)[middle]) < 0.2 * np.std(_turns(circle)[middle])
    radius = np.linalg.norm(smooth, axis=1)
    assert np.max(np.abs(radius - 5e-3)) < 0.1 * UM


def test_smoothing_moves_a_vertex_at_most_its_limit():
    P = np.column_stack((np.arange(11) * 1e-4, np.zeros(11)))
    P[5, 1] = 20 * UM  # a spike the quadratic pulls most of the way back
    inner = np.r_[False, np.ones(9, dtype=bool), False]
    limit = np.full(11, 2.5 * UM)
    smooth = smooth_vertices(P, inner, limit, SMOOTH_REACH)
    shift = np.linalg.norm(smooth - P, axis=1)
    assert shift[5] == pytest.approx(2.5 * UM, rel=1e-12)
    assert np.all(shift <= limit * (1 + 1e-12))
    assert np.all(smooth[[0, 10]] == P[[0, 10]])


def test_only_gentle_vertices_between_short_feed_moves_that_are_not_pinned_may_move():
    # 0.1 mm moves along X, a 90-degree turn at vertex 4, a long move from vertex 7 on.
    P = np.array([[k * 1e-4, 0.0] for k in range(5)] + [[4e-4, k * 1e-4] for k in (1, 2, 3)])
    P = np.vstack((P, P[-1] + [0.0, 2 * SMOOTH_MOVE_M], P[-1] + [0.0, 2 * SMOOTH_MOVE_M + 1e-4]))
    n = len(P) - 1
    rapid = np.zeros(n, dtype=bool)
    arc = np.zeros(n, dtype=bool)
    fixed = np.zeros(n + 1, dtype=bool)
    movable = movable_vertices(P, rapid, arc, fixed)
    assert movable.tolist() == [False, True, True, True, False, True, True, False, False, False]
    rapid[0] = arc[5] = True
    fixed[2] = True
    assert np.flatnonzero(movable_vertices(P, rapid, arc, fixed)).tolist() == [3]
    # The blends at a movable vertex and its neighbours keep what smoothing leaves.
    tol = np.full(n + 1, 1e-5)
    assert np.flatnonzero(blend_tolerance(tol, movable) < tol).tolist() == list(range(8))
    assert blend_tolerance(tol, movable)[1] == pytest.approx((1 - SMOOTH_SHARE) * 1e-5)


def _gentle_curve(count: int) -> np.ndarray:
    """Vertices of a wave in 0.1 mm steps: turning least at its inflections (every 31.4 mm)."""
    x = np.arange(count) * 1e-4
    return np.column_stack((x, 2e-3 * np.sin(x / 5e-3)))


def test_a_forced_break_goes_to_where_the_curve_turns_least_and_stays_there():
    P = _gentle_curve(1200)
    natural = np.zeros(1200, dtype=bool)
    natural[0] = True  # the program's start: a stop
    decided: dict[int, int] = {}
    forced = forced_breaks(P, natural, g0=0, spacing=400, stable=1150, final=False, decided=decided)
    # Candidates 400 and 800 are decided, each at the node within 400/8 that turns least;
    # 0 is the program's start, a stop (no break needed); 1200 is not listed.
    turn = _turns(P)
    for key in (400, 800):
        at = decided[key]
        assert abs(at - key) <= 50
        assert turn[at - 1] == pytest.approx(np.min(turn[key - 51 : key + 50]))
    assert decided[0] == -1 and set(decided) == {0, 400, 800}
    assert np.flatnonzero(forced).tolist() == [decided[400], decided[800]]
    # A later window listing from node 300 on keeps both decisions, whatever it would find.
    bent = P[300:] + np.random.default_rng(1).normal(0.0, 1e-6, (900, 2))
    later = forced_breaks(
        bent, natural[300:], g0=300, spacing=400, stable=850, final=False, decided=decided
    )
    assert (np.flatnonzero(later) + 300).tolist() == [decided[400], decided[800]]


def test_no_forced_break_near_a_natural_one_nor_in_the_last_window():
    P = _gentle_curve(1000)
    natural = np.zeros(1000, dtype=bool)
    natural[0] = True
    natural[450] = True  # a dwell within a quarter spacing of candidate 400
    decided: dict[int, int] = {}
    forced = forced_breaks(P, natural, g0=0, spacing=400, stable=990, final=False, decided=decided)
    assert decided[400] == -1 and decided[800] >= 750
    assert np.flatnonzero(forced).tolist() == [decided[800]]
    # Candidate 800's neighbourhood (700..900) is listed: decided; one near the end is not
    # decided and forced where it is, unless the window is the program's last.
    tail = forced_breaks(P, natural, g0=0, spacing=400, stable=850, final=False, decided={})
    assert tail[800] and not tail[400]
    last = forced_breaks(P, natural, g0=0, spacing=400, stable=999, final=True, decided={})
    assert not last.any()
    # The last window keeps the breaks decided before it only within the committed motion's
    # reach (`beyond` marks the rest).
    decided = {400: 380, 800: 810}
    beyond = np.arange(1000) > 600
    kept = forced_breaks(
        P, natural, g0=0, spacing=400, stable=999, final=True, decided=decided, beyond=beyond
    )
    assert np.flatnonzero(kept).tolist() == [380]
    planned = forced_breaks(
        P, natural, g0=0, spacing=400, stable=850, final=False, decided=decided, beyond=beyond
    )
    assert np.flatnonzero(planned).tolist() == [380, 810]


def _cam_wave(count: int, tolerance_mm: float) -> tuple[str, np.ndarray]:
    """A CAM wave in moves of about 0.15 mm rounded to 1 um, and its vertices [m]."""
    x = np.arange(1, count + 1) * 0.15
    y = 3.0 * np.sin(x / 4.0)
    points = np.round(np.column_stack((x, y)), 3)
    body = "\n".join(f"X{px:.3f} Y{py:.3f}" for px, py in points)
    program = f"G21 G90 G64 P{tolerance_mm} G1 X0 Y0 F3000\n{body}\nM2"
    vertices = np.vstack(([0.0, 0.0], points)) * 1e-3
    return program, vertices


def _assert_within_limits(traj: SampledTrajectory, config) -> None:
    """v, a and j of every axis from differences of the sampled positions within its limits."""
    period = config.interpolation_period_s
    v, a, j = (
        np.max(np.abs(np.diff(traj.pos_m, n=k, axis=0)), axis=0) / period**k for k in (1, 2, 3)
    )
    assert np.all(v <= np.array(config.v_max) * (1 + 1e-6))
    assert np.all(a <= np.array(config.a_max) * (1 + 1e-6))
    assert np.all(j <= np.array(config.j_max) * (1 + 1e-6))


def test_a_smoothed_cam_curve_streams_in_windows_as_planned_at_once_within_the_tolerance():
    # Windows of 40 moves commit at breaks (forced ones, smoothing frozen at each commit);
    # the joined trajectory holds the limits and the tolerance of the programmed polyline.
    program, vertices = _cam_wave(400, 0.01)
    small = dataclasses.replace(CONFIG, lookahead_segments=40)
    joined = SampledTrajectory.concatenate(list(plan_program_stream(program, small)))
    whole = plan_program(program, CONFIG)
    for traj, config in ((joined, small), (whole, CONFIG)):
        _assert_within_limits(traj, config)
        figures = trajectory_figures(traj, programmed_path(program, config))
        assert figures.path_dev_max_m <= 1e-5 * (1 + 1e-6)
    np.testing.assert_allclose(joined.pos_m[-1], whole.pos_m[-1], atol=1e-15)
    assert joined.t_s[-1] >= whole.t_s[-1] - 1e-9
    assert math.isclose(whole.pos_m[-1, 0], vertices[-1, 0], abs_tol=1e-15)


def test_a_streamed_cam_curve_slows_only_where_a_window_commits():
    # A forced break squeezes its neighbours' blends: the curve slows there. Windows of 400
    # moves (breaks every 100) plan only the break they commit at (and those after it, which
    # a later window may commit at); the last window plans none beyond the committed
    # motion's reach. So the speed dips once per commit, and once at the program's end.
    program, _ = _cam_wave(1200, 0.01)
    config = dataclasses.replace(CONFIG, lookahead_segments=400)
    chunks = list(plan_program_stream(program, config))
    traj = SampledTrajectory.concatenate(chunks)
    _assert_within_limits(traj, config)
    speed = np.linalg.norm(np.diff(traj.pos_m, axis=0), axis=1) / config.interpolation_period_s
    slow = speed < 0.7 * np.max(speed)
    dips = np.count_nonzero(slow[1:] & ~slow[:-1])
    assert 1 <= dips <= len(chunks)  # commits: one fewer than the chunks
