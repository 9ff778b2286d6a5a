"""Each planner stage on its own: move limits, corner blends, chains + speed profile, sampling."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from feed_twin.gcode.plan_blends import (
    NodeFlags,
    corner_blends,
    fitted_widths,
    zone_coefficients,
)
from feed_twin.gcode.plan_chains import chain_bodies
from feed_twin.gcode.plan_limits import AxisLimits, move_limits
from feed_twin.gcode.plan_profile import Pieces, motion_pieces, speed_profile, speeds_fit
from feed_twin.gcode.plan_sampling import piece_starts, sample_indices, sample_path
from feed_twin.gcode.profile import evaluate_path, sample_pieces

LIMITS = AxisLimits(
    v_max=np.array([0.5, 0.25]),  # [m/s]
    rapid=np.array([1.0, 0.4]),
    a_max=np.array([2.0, 1.0]),  # [m/s^2]
    j_max=np.array([20.0, 40.0]),  # [m/s^3]
    jerk=True,  # caps hold the jerk; no filter window: the raw plan's kernels on their own
    filter_n=1,
    window_s=0.0,
    period_s=1e-3,
)


def _flags(n: int, tol: float) -> NodeFlags:
    stop = np.zeros(n + 1, dtype=bool)
    stop[0] = stop[n] = True
    return NodeFlags(
        tol=np.full(n + 1, tol),
        stop=stop,
        has_entries=np.zeros(n + 1, dtype=bool),
        forced=np.zeros(n + 1, dtype=bool),
    )


def _pieces(points, feeds, limits: AxisLimits, tol: float = 2e-5):
    n = len(feeds)
    moves = move_limits(points, [False] * n, feeds, limits)
    flags = _flags(n, tol)
    blends = corner_blends(moves, flags, limits, None)
    bodies = chain_bodies(moves, blends, flags, limits, first=0, open_end=False)
    assert bodies is not None
    speeds = speed_profile(bodies, v_first=0.0)
    pieces = motion_pieces(bodies, speeds, q_commit=len(bodies.length), n_moves=n)
    return moves, blends, bodies, pieces


def _sample_s(pieces: Pieces, dt: float):
    t0, t_end = piece_starts(pieces, 0.0)
    times = np.arange(0.0, t_end + dt, dt)
    p = pieces
    s, sd, sdd, _ = sample_pieces(
        times, p.kind, t0, p.dur, p.s0, p.v0, p.vp, p.v1, p.A, p.t_up, p.t_cruise
    )
    return times, s, sd, sdd, t_end


def test_move_limits_cap_each_axis_exactly_at_its_limit_on_a_diagonal():
    # Direction (0.6, 0.8): Y limits speed and acceleration, X limits jerk.
    moves = move_limits(
        [(0.0, 0.0), (3e-3, 4e-3), (3e-3, 4e-3 + 5e-3)], [False, True], [1.0, 0.0], LIMITS
    )
    assert pytest.approx([5e-3, 5e-3], rel=1e-15) == moves.L
    diagonal_axis = np.abs(moves.u[0])
    assert diagonal_axis * moves.V[0] == pytest.approx([0.1875, 0.25], rel=1e-15)
    assert diagonal_axis * moves.A[0] == pytest.approx([0.75, 1.0], rel=1e-15)
    assert diagonal_axis * moves.J[0] == pytest.approx([20.0, 20.0 * 0.8 / 0.6], rel=1e-15)
    # A rapid along Y alone runs at Y's rapid rate; X, which does not move, sets no limit.
    assert (moves.V[1], moves.A[1], moves.J[1]) == (0.4, 1.0, 40.0)
    # A programmed feed below the axis limits is the speed cap.
    slow = move_limits([(0.0, 0.0), (3e-3, 4e-3)], [False], [0.01], LIMITS)
    assert slow.V[0] == 0.01


def test_trapezoid_limits_have_no_jerk_limit():
    trapezoid = AxisLimits(**{**LIMITS.__dict__, "jerk": False})
    assert move_limits([(0.0, 0.0), (1e-3, 0.0)], [False], [1.0], trapezoid).J[0] == np.inf


def test_corner_blend_stays_within_the_tolerance_and_its_speed_within_the_axis_limits():
    tol = 2e-4
    points = [(0.0, 0.0), (0.02, 0.0), (0.04, 0.01), (0.06, 0.0)]  # turns of 27 and 53 degrees
    moves, blends, _, _ = _pieces(points, [0.05, 0.05, 0.05], LIMITS, tol)
    inner = slice(1, 3)
    assert np.all(blends.w[inner] > 0.0) and not blends.stop[inner].any()
    deviation = np.linalg.norm(blends.dU, axis=1) * blends.w / 6.0
    assert np.all(deviation <= tol * (1.0 + 1e-12))
    # The corner speed keeps every axis's curvature acceleration and jerk within its limits.
    cap = blends.cap[inner, None]
    assert np.all(blends.a_node[inner] * cap**2 <= LIMITS.a_max * (1.0 + 1e-12))
    assert np.all(blends.j_node[inner] * cap**3 <= LIMITS.j_max * (1.0 + 1e-12))
    # The blended path itself passes the corner vertex at |dU| w/6, within tol.
    S = np.concatenate(([0.0], np.cumsum(moves.L)))
    s = np.linspace(0.0, S[-1], 200001)
    n = len(moves.L)
    pos, _, _, _ = evaluate_path(
        s, np.ones_like(s), np.zeros_like(s), S[:-1], moves.L, moves.P[:-1], moves.P[1:],
        moves.u, blends.w[:n], blends.dU[:n], blends.w[1:], blends.dU[1:],
        np.zeros(len(s), dtype=np.int64),
    )  # fmt: skip
    for k in (1, 2):
        closest = np.min(np.linalg.norm(pos - moves.P[k], axis=1))
        assert closest == pytest.approx(deviation[k], rel=1e-3)
        assert closest <= tol * (1.0 + 1e-6)  # sampled s: at or just above the apex


def test_a_corner_crossed_below_its_cap_is_narrowed_to_the_width_that_speed_needs():
    # A 90-degree corner (dU = (-1, 1)): its blend of the tolerance's width allows cap; crossed
    # at cap / 3, the narrowest blend for that speed has |dU_i| v^3 / w^2 = j_max_i (X binds:
    # j 20 against Y's 40) or |dU_i| v^2 / w = a_max_i, whichever is wider.
    tol = 2e-5
    points = [(0.0, 0.0), (0.01, 0.0), (0.01, 0.01)]
    moves, blends, _, _ = _pieces(points, [0.05, 0.05], LIMITS, tol)
    node = np.array([0, 1, 2])
    cap = blends.cap[1]
    assert blends.alone[1] and blends.w[1] == pytest.approx(6 * tol / np.sqrt(2), rel=1e-12)
    v = np.array([0.0, cap / 3.0, 0.0])
    held = np.ones(3, dtype=bool)  # extended: the raw plan holds each node's speed around it
    w_limit = fitted_widths(blends, node, v, LIMITS, extended=held, last=2)
    assert w_limit is not None and np.isinf(w_limit[[0, 2]]).all()
    w_jerk = np.sqrt(v[1] ** 3 / LIMITS.j_max[0])
    w_acc = v[1] ** 2 / LIMITS.a_max[1]
    assert w_limit[1] == pytest.approx(max(w_jerk, w_acc), rel=1e-5)
    narrow = corner_blends(moves, _flags(2, tol), LIMITS, None, w_limit=w_limit)
    assert narrow.w[1] == w_limit[1] < blends.w[1]
    assert narrow.cap[1] == pytest.approx(v[1], rel=1e-5) and narrow.cap[1] >= v[1]
    # At its cap, beyond what the window commits, not extended (its blend counts in the
    # chains' limits) or without a jerk limit, nothing narrows.
    at_cap = np.array([0.0, cap, 0.0])
    assert fitted_widths(blends, node, at_cap, LIMITS, extended=held, last=2) is None
    assert fitted_widths(blends, node, v, LIMITS, extended=held, last=0) is None
    assert fitted_widths(blends, node, v, LIMITS, extended=~held, last=2) is None
    trapezoid = AxisLimits(**{**LIMITS.__dict__, "jerk": False})
    assert fitted_widths(blends, node, v, trapezoid, extended=held, last=2) is None


def test_speed_profile_keeps_v_a_within_limits_and_integrates_to_the_length():
    limits = LIMITS
    points = [(0.0, 0.0), (0.03, 0.0), (0.03, 0.002)]
    moves, _, bodies, pieces = _pieces(points, [0.3, 0.3], limits)
    dt = 1e-5
    _, s, sd, sdd, t_end = _sample_s(pieces, dt)
    assert s[-1] == pytest.approx(float(np.sum(moves.L)), abs=1e-12)
    # The speed integrates to the distance covered (trapezoid rule on a fine grid).
    assert np.sum(0.5 * (sd[1:] + sd[:-1]) * dt) == pytest.approx(s[-1] - s[0], rel=1e-6)
    assert np.all(sd >= -1e-15) and np.all(sd <= max(bodies.V) * (1.0 + 1e-12))
    assert np.all(np.abs(sdd) <= max(bodies.A) * (1.0 + 1e-9))
    assert sd[0] == 0.0 and sd[-1] == pytest.approx(0.0, abs=1e-12)


def test_speeds_fit_tells_a_start_the_bodies_cannot_brake_from():
    # seed 24 of benchmarks/lookahead_limits.py at look-ahead 16 in one body: 68.5 mm/s
    # committed, 13.7 mm/s allowed 7.86 mm on at A = 0.147 m/s^2 (the committed window saw
    # A = 0.299 and a stop): v^2 = 13.7^2 + 2 A L gives 50.0 mm/s, not 68.5.
    limits = LIMITS
    moves, _, bodies, _ = _pieces([(0.0, 0.0), (0.00786, 0.0)], [0.3], limits)
    bodies = dataclasses.replace(
        bodies, A=np.array([0.147]), cap=np.array([0.3, 0.0137]), length=np.array([0.00786])
    )
    reachable = np.sqrt(0.0137**2 + 2.0 * 0.147 * 0.00786)
    assert reachable == pytest.approx(0.0500, abs=1e-4)
    for v_first, fits in ((0.0685, False), (reachable * (1.0 - 1e-6), True)):
        speeds = speed_profile(bodies, v_first=v_first)
        assert speeds.v[0] == v_first
        assert speeds_fit(bodies, speeds.v) is fits
    assert speeds_fit(bodies, np.array([0.0, 0.0138])) is False  # above the end's cap
    held = dataclasses.replace(bodies, hold_in=np.array([0.0, 0.55]))  # 0.55 s at the end
    assert speeds_fit(held, np.array([0.0, 0.0137])) is False  # 7.54 + 0.64 mm > 7.86 mm ...
    assert speeds_fit(held, np.array([0.0, 0.0130])) is True  # ... 7.15 + 0.57 mm fits


def test_sampler_positions_equal_the_analytic_trapezoid():
    # X alone: V = 0.1 m/s, A = 1 m/s^2 over 20 mm: ramps of 0.1 s (5 mm), 0.1 s at cruise.
    limits = AxisLimits(
        v_max=np.array([0.1]), rapid=np.array([0.1]), a_max=np.array([1.0]),
        j_max=np.array([100.0]), jerk=False, filter_n=1, window_s=0.0, period_s=1e-3,
    )  # fmt: skip
    moves = move_limits([(0.0,), (0.02,)], [False], [1.0], limits)
    flags = _flags(1, 2e-5)
    blends = corner_blends(moves, flags, limits, None)
    bodies = chain_bodies(moves, blends, flags, limits, first=0, open_end=False)
    assert bodies is not None
    speeds = speed_profile(bodies, v_first=0.0)
    pieces = motion_pieces(bodies, speeds, q_commit=1, n_moves=1)
    t0, t_end = piece_starts(pieces, 0.0)
    assert t_end == pytest.approx(0.3, rel=1e-12)
    period = 1e-3
    k0, k1 = sample_indices(0, t_end, period, final=True)
    t = np.arange(k0, k1) * period
    pos, vel, acc, _, _ = sample_path(t, pieces, t0, moves, blends.w, blends.dU)
    tc = np.clip(t, 0.0, 0.3)
    x = np.where(
        tc < 0.1,
        0.5 * tc**2,
        np.where(tc < 0.2, 0.005 + 0.1 * (tc - 0.1), 0.02 - 0.5 * (0.3 - tc) ** 2),
    )
    v = np.where(tc < 0.1, tc, np.where(tc < 0.2, 0.1, 0.3 - tc))
    assert pos[:, 0] == pytest.approx(x, abs=1e-12)
    assert vel[:, 0] == pytest.approx(v, abs=1e-12)
    assert t[-1] >= t_end and pos[-1, 0] == 0.02
    assert np.all(np.abs(acc[:, 0]) <= 1.0 + 1e-12)


def test_cruise_cap_with_curvature_steps_solves_the_cubic_exactly():
    filtered = AxisLimits(**{**LIMITS.__dict__, "window_s": 0.05, "filter_n": 51})
    j = np.array([[2e4, 0.0], [0.0, 0.0], [5e3, 1e3]])  # [1/m^2]
    kick = np.array([[3.0, 0.0], [0.0, 2.0], [0.0, 0.0]])  # [1/m]
    cap = filtered.cruise_cap(np.zeros_like(j), j, 1.0, 0.75, kick)
    c = filtered.kick_jerk(kick)
    used = j * cap[:, None] ** 3 + c * cap[:, None] ** 2
    budget = 0.75 * filtered.j_max
    assert np.all(used <= budget * (1 + 1e-12))
    # The binding axis of each row sits on its budget.
    np.testing.assert_allclose(np.max(used / budget, axis=1), 1.0, rtol=1e-9)
    assert c[0, 0] == pytest.approx(1.5 * 3.0 / 1e-3)


def test_a_short_zone_of_one_blend_is_a_curvature_step():
    # Chords 1.0, 0.95, 0.9 along a gentle curve: on the middle move the end blend (width
    # 0.9) leaves 0.05 of the start blend (width 0.95) alone, a curvature step dU / w^2 * 0.05.
    L = np.array([1.0, 0.95, 0.9])
    w = np.array([0.0, 0.95, 0.9, 0.0])
    du = np.array([[0.0], [0.02], [0.02], [0.0]])
    *_, j_s, j_e, kick = zone_coefficients(L, w, du, steps=False)
    assert j_s[1, 0] == pytest.approx(0.02 / 0.95**2) and np.all(kick == 0.0)
    *_, j_s, j_e, kick = zone_coefficients(L, w, du, steps=True)
    assert kick[1, 0] == pytest.approx(0.02 / 0.95**2 * 0.05)
    both = abs(0.02 / 0.81 - 0.02 / 0.95**2)  # overlap, plus the step spread over the move
    assert j_s[1, 0] == pytest.approx(both + kick[1, 0] / 0.95)


def test_isolated_curvature_steps_count_as_the_samples_see_them():
    # Chords on a circle of R = 5 mm growing 6 um each (a constant X step across a curve):
    # every move's end blend runs alone over the last 6 um, a curvature step next to each
    # node. At 50 mm/s a sample travels 0.15 mm in 3 periods, less than the 0.2 mm where
    # both blends of a move overlap: the third differences of the positions see one step at
    # a time (3/4 K v^2 / period), half the two steps per node counted before.
    filtered = AxisLimits(**{**LIMITS.__dict__, "window_s": 0.05, "filter_n": 51})
    R, v, dt = 5e-3, 0.05, filtered.period_s
    lengths = 2e-4 + 6e-6 * np.arange(16)
    heading = np.concatenate(([0.0], np.cumsum(lengths[:-1] / R)))
    steps = lengths[:, None] * np.column_stack((np.cos(heading), np.sin(heading)))
    points = np.vstack(([0.0, 0.0], np.cumsum(steps, axis=0)))
    n = len(lengths)
    moves = move_limits(points, [False] * n, [v] * n, filtered)
    blends = corner_blends(moves, _flags(n, 1e-4), filtered, None)
    *_, kick = zone_coefficients(moves.L, blends.w, blends.dU, steps=True)
    # Node k: the step ending it (move k-1's only one) at 3/4, where the larger of the moves'
    # totals next to it counted twice before.
    inner = slice(2, n - 2)
    np.testing.assert_allclose(blends.k_node[1:n][inner], 0.5 * kick[:-1][inner], rtol=1e-12)
    assert np.all(kick[:-1][inner] > 0.0)
    # The samples at constant speed, at any phase, stay within what the caps count.
    S = np.concatenate(([0.0], np.cumsum(moves.L)))
    bound = np.max(
        blends.j_node[3 : n - 2] * v**3 + filtered.kick_jerk(blends.k_node[3 : n - 2]) * v**2,
        axis=0,
    )
    seen = np.zeros(2)
    for phase in np.linspace(0.0, 1.0, 16, endpoint=False):
        s = S[3] + v * dt * (phase + np.arange(int((S[n - 3] - S[3]) / (v * dt))))
        pos, *_ = evaluate_path(
            s, np.full(len(s), v), np.zeros(len(s)), S[:-1], moves.L, moves.P[:-1],
            moves.P[1:], moves.u, blends.w[:n], blends.dU[:n], blends.w[1:], blends.dU[1:],
            np.zeros(len(s), dtype=np.int64),
        )  # fmt: skip
        seen = np.maximum(seen, np.max(np.abs(np.diff(pos, n=3, axis=0)), axis=0) / dt**3)
    assert np.all(seen <= bound), (seen, bound)
    assert np.max(seen / bound) > 0.5, (seen, bound)
