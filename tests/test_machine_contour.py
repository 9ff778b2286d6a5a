"""Contour error of the machine twin: the pure measure against closed forms, and the in-process
multi-axis run against two matched first-order loops."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode.geometry import programmed_path
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.contour import contour_error
from feed_twin.machine.simulate import simulate_machine

ROOT = Path(__file__).resolve().parents[1]
MACHINE = load_machine_config(ROOT / "config" / "machine_default.yaml")
CIRCLE = "G90 G17 G21 G54\nG0 X50 Y0\nG3 X50 Y0 I-50 J0 F{feed}\nG3 X50 Y0 I-50 J0\nM2\n"


def test_contour_error_of_a_shrunk_lagging_circle_is_its_radius_loss_and_arc_lag():
    nc = dataclasses.replace(MACHINE.nc, chord_tolerance_m=1e-7)
    program = CIRCLE.format(feed=6000)
    segments = programmed_path(program, nc)
    R, d, phase = 0.05, 20e-6, 0.01  # [m], [m], [rad]
    theta = np.linspace(0.3, 5.9, 200)
    centre = np.array(nc.work_offsets_m.G54[:3])
    command = np.zeros((len(theta), 4))
    command[:, 0] = centre[0] + R * np.cos(theta)
    command[:, 1] = centre[1] + R * np.sin(theta)
    command[:, 2] = nc.start_position[2]
    vel = np.zeros_like(command)
    vel[:, 0], vel[:, 1] = -np.sin(theta), np.cos(theta)
    tool = command.copy()
    tool[:, 0] = centre[0] + (R - d) * np.cos(theta - phase)
    tool[:, 1] = centre[1] + (R - d) * np.sin(theta - phase)
    tool[:, 3] = 1.0  # a rotary axis far off does not count
    line = np.full(len(theta), 3)
    result = contour_error(theta, line, tool, command, vel, segments, n_linear=3)
    assert np.allclose(result.normal_m, d, rtol=0, atol=1e-12)
    # t = (-sin, cos)(theta): c . t = 0 and p . t = -(R - d) sin(phase)
    expected_lag = (R - d) * math.sin(phase)
    assert np.allclose(result.lag_m, expected_lag, rtol=1e-9)
    summary = result.summary()
    assert summary["contour_error_max_m"] == pytest.approx(d, abs=1e-12)
    assert summary["contour_error_rms_m"] == pytest.approx(d, abs=1e-12)
    assert summary["contour_error_max_line"] == 3


def test_twin_circle_without_feed_forward_shrinks_by_v2_over_2_r_kv2():
    machine = MACHINE.select(["X", "Y"])
    axes = {}
    for name, axis in machine.axes.items():
        position = dataclasses.replace(
            axis.controller.position,
            velocity_ff=0.0,
            acceleration_ff=0.0,
            following_error_limit_m=0.02,
        )
        axes[name] = dataclasses.replace(
            axis, controller=dataclasses.replace(axis.controller, position=position)
        )
    jerk = tuple(dataclasses.replace(a, j_max_m_s3=3 * a.j_max_m_s3) for a in machine.nc.axes)
    nc = dataclasses.replace(machine.nc, axes=jerk, lookahead_segments=100000)
    machine = dataclasses.replace(machine, axes=axes, nc=nc)
    run = simulate_machine(machine, CIRCLE.format(feed=6000), settle_s=0.05)
    turn = run.line == 4
    centre = np.array(nc.work_offsets_m.G54[:2])
    rho_cmd = np.linalg.norm(run.command[turn, :2] - centre, axis=1)
    rho_twin = np.linalg.norm(run.actual[turn, :2] - centre, axis=1)
    # the second turn: steady after the first (5/Kv = 0.17 s of a 3.1 s turn) until its end
    steady = slice(len(rho_cmd) // 10, -len(rho_cmd) // 10)
    v, R, kv = 0.1, 0.05, 30.0
    closed = v * v / (2 * R * kv * kv)
    assert np.mean(rho_cmd[steady] - rho_twin[steady]) == pytest.approx(closed, rel=0.05)
    # the along-path lag of a P loop is v/Kv
    assert np.median(run.contour.lag_m[turn][steady]) == pytest.approx(v / kv, rel=0.05)
    fe_x = np.abs(run.following_error("X")[turn][steady])
    assert np.max(fe_x) == pytest.approx(v / kv, rel=0.05)
    # the rapid to the start (0.5 m/s) lags by up to 0.5/Kv = 17 mm
    assert 0.005 < run.summary()["following_error_max_m"]["x"] < 0.5 / kv
    assert run.simulated == ("X", "Y")
    # Z and B have no plant here: their twin is their command
    assert np.array_equal(run.actual[:, 2:], run.command[:, 2:])


def test_rotary_axis_is_recorded_as_its_command_and_left_out_of_the_contour():
    machine = MACHINE.select(["X"])
    run = simulate_machine(machine, "G1 B0\nG1 X10 B30 F3000\nM2\n", settle_s=0.05)
    b = run.axes.index("B")
    assert run.command[-1, b] == pytest.approx(math.radians(30.0))
    assert np.array_equal(run.actual[:, b], run.command[:, b])
    assert run.summary()["contour_error_max_m"] < 2e-4  # X lags < v/Kv across the line
