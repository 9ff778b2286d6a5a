"""Chain ends held on their straight side (`plan_chains._held_chain_ends`): a straight move
next to a chain of arc chords runs at its own limits, not at the chain's speed cap."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.gcode.plan_chains import CHAIN_CUT_NODE, CHAIN_ENTRY, CHAIN_EXIT, SINGLE
from feed_twin.gcode.plan_chains import _held_chain_ends as held_chain_ends  # pyright: ignore[reportPrivateUsage]

ROOT = Path(__file__).resolve().parent.parent
CONFIG = load_nc_config(ROOT / "config" / "axis_default.yaml")
T = 0.05  # [s]
# A 20 mm line, a tangent quarter circle of R 5 mm, a 20 mm line, at F 100 mm/s.
PROGRAM = "G21 G90 G54 G64 P0.01\nG1 X20 Y0 F6000\nG3 X25 Y5 R5\nG1 Y25\nM2\n"


def test_chain_ends_are_held_where_the_straight_body_has_room_and_a_held_end():
    kind = np.array([SINGLE, CHAIN_ENTRY, CHAIN_CUT_NODE, CHAIN_EXIT, CHAIN_ENTRY, CHAIN_EXIT])
    cap = np.full(6, 0.1)  # [m/s]: a hold needs 2 T cap = 10 mm of its body
    length = np.array([0.02, 1e-3, 1e-3, 0.02, 1e-3])
    extended = np.array([True, False, False, False, False, False])
    entry, exit_ = held_chain_ends(kind, cap, length, extended, T)
    # The first entry follows an extended corner; the exit and the next entry share a 20 mm
    # straight body and hold each other's side; the last exit ends the window (no body).
    np.testing.assert_array_equal(entry, [False, True, False, False, True, False])
    np.testing.assert_array_equal(exit_, [False, False, False, True, False, False])
    # A body shorter than 2 T cap, or a far end that is not held: no hold.
    short = length.copy()
    short[3] = 9e-3
    entry, exit_ = held_chain_ends(kind, cap, short, extended, T)
    assert not entry[4] and not exit_[3] and entry[1]
    entry, _ = held_chain_ends(kind, cap, length, np.zeros(6, dtype=bool), T)
    assert not entry[1]


def test_a_line_into_a_tangent_arc_runs_at_its_feed_and_the_axes_keep_their_limits():
    traj = plan_program(PROGRAM, CONFIG)
    period = CONFIG.interpolation_period_s
    speed = np.linalg.norm(np.diff(traj.pos_m, axis=0), axis=1) / period
    on_line = traj.line[1:] == 2
    # Held on the line only just before the arc (the chain's cap there), at F elsewhere.
    assert np.max(speed[on_line]) > 0.99 * 0.1
    peaks = [np.max(np.abs(np.diff(traj.pos_m, n=k, axis=0)), axis=0) / period**k for k in (2, 3)]
    assert np.all(peaks[0] <= np.array(CONFIG.a_max) * (1 + 1e-6))
    assert np.all(peaks[1] <= np.array(CONFIG.j_max) * (1 + 1e-6))
    # The arc's entry and exit caps no longer slow the whole of both lines: quicker than
    # both lines at that cap (the arc's mean speed), which is what the plan did before.
    trapezoid = plan_program(PROGRAM, dataclasses.replace(CONFIG, profile="trapezoid"))
    arc = traj.line[1:] == 3
    v_arc = float(np.mean(speed[arc]))
    assert len(traj) * period < 0.04 / v_arc + 0.5 * np.pi * 5e-3 / v_arc
    assert len(traj) > len(trapezoid)  # the jerk limit still costs time
