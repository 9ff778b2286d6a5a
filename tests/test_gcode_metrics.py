"""Trajectory figures against closed forms: a perturbed circle and helix, a filleted corner."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import SampledTrajectory, load_nc_config, plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.metrics import (
    CORNER_RESOLUTION,
    blended_corners,
    requirement_failures,
    trajectory_figures,
)

FIXTURES = Path(__file__).parent / "fixtures" / "gcode"
CONFIG = load_nc_config(FIXTURES / "nc_test.yaml")
PERIOD = CONFIG.interpolation_period_s
MM = 1e-3


def trajectory(pos: np.ndarray, line: np.ndarray | int = 1) -> SampledTrajectory:
    n = len(pos)
    zeros = np.zeros_like(pos)
    return SampledTrajectory(
        t_s=np.arange(n) * PERIOD,
        axes=CONFIG.axis_names,
        pos_m=pos,
        vel_m_s=zeros,
        acc_m_s2=zeros,
        line=np.broadcast_to(np.asarray(line, dtype=np.int64), (n,)).copy(),
        events=(),
    )


def circle_samples(R: float, omega: float, turns: float, radial, axial_per_rad: float = 0.0):
    """Clockwise from (R, 0) about the origin, radius R + radial(theta), z = axial * theta."""
    t = np.arange(int(turns * 2 * math.pi / omega / PERIOD) + 1) * PERIOD
    theta = -omega * t
    r = R + radial(theta)
    return np.column_stack((r * np.cos(theta), r * np.sin(theta), axial_per_rad * theta))


def test_circle_with_a_known_radial_ripple_and_its_closed_form_peaks():
    R, omega, ripple = 10 * MM, 5.0, 1.5e-6
    segments = programmed_path("G17 G1 X10 F1000\nG2 X10 Y0 I-10 J0", CONFIG)
    assert [s.arc is None for s in segments] == [True, False]
    pos = circle_samples(R, omega, 1.0, lambda th: ripple * np.sin(3 * th) ** 2)
    figures = trajectory_figures(trajectory(pos, line=2), segments)
    # The distance from a circle of a point at radius R + d is |d|; the ripple peaks at 1.5 um.
    assert figures.arc_dev_max_m == pytest.approx(ripple, rel=1e-6)
    assert figures.path_dev_max_m == pytest.approx(ripple, rel=1e-6)
    assert requirement_failures(figures, chord_tolerance_m=1e-6) == [
        "arc sample 1.500 um from its circle (chord_tolerance_m 1.000 um)"
    ]
    # Differences of samples on a circle: v = w R, a = w^2 R, j = w^3 R per axis at the peaks,
    # to O((w T)^2), plus the ripple's share (its sixth harmonic multiplies it by 6^k).
    assert figures.peak_vel_m_s[:2] == pytest.approx((omega * R,) * 2, rel=2e-3)
    assert figures.peak_acc_m_s2[:2] == pytest.approx((omega**2 * R,) * 2, rel=1e-2)
    assert figures.peak_jerk_m_s3[:2] == pytest.approx((omega**3 * R,) * 2, rel=5e-2)
    assert figures.program_time_s == pytest.approx((len(pos) - 1) * PERIOD, abs=1e-12)
    # The line meets the circle at 90 degrees in (10, 0): samples near it belong to that
    # corner's blend zone, not to the arc.
    zone = figures.corners[0].zone_m
    assert figures.arc_samples == pytest.approx(
        len(pos) * (1 - 2 * zone / (2 * math.pi * R)), abs=3
    )


def test_helix_distance_counts_an_axial_offset_across_the_helix_only():
    R, pitch, offset = 10 * MM, 10 * MM, 1e-6
    program = "G17 G1 X10 F1000\nG2 X10 Y0 Z-20 I-10 J0 P2"
    segments = programmed_path(program, CONFIG)
    rate = pitch / (2 * math.pi)  # [m/rad]
    # The helix samples shifted along z by 1 um: the distance is 1 um times cos(helix angle).
    pos = circle_samples(R, 4.0, 2.0, lambda th: 0.0 * th, axial_per_rad=rate)
    pos[:, 2] -= offset
    figures = trajectory_figures(trajectory(pos, line=2), segments)
    expected = offset * R / math.hypot(R, rate)
    assert figures.arc_dev_max_m == pytest.approx(expected, rel=1e-4)
    assert expected < 0.99 * offset  # the projection matters at this pitch


def fillet_samples(r: float, v: float) -> np.ndarray:
    """Along +x to the corner at (2, 0) mm, a fillet of radius r, then along +y: speed v.

    The samples are spaced v*T along the path, one of them in the fillet's middle.
    """
    vertex = np.array([2 * MM, 0.0])
    length_in = vertex[0] - r
    arc = 0.5 * math.pi * r
    middle = length_in + 0.5 * arc
    s = middle + np.arange(-int(middle / (v * PERIOD)), int(middle / (v * PERIOD))) * v * PERIOD
    xy = np.empty((len(s), 2))
    before = s < length_in
    xy[before] = np.column_stack((s[before], 0.0 * s[before]))
    on_arc = (s >= length_in) & (s < length_in + arc)
    phi = (s[on_arc] - length_in) / r
    centre = vertex + np.array([-r, r])
    xy[on_arc] = np.column_stack((centre[0] + r * np.sin(phi), centre[1] - r * np.cos(phi)))
    after = s >= length_in + arc
    xy[after] = np.column_stack((0 * s[after] + vertex[0], r + s[after] - length_in - arc))
    return np.column_stack((xy, np.zeros(len(s))))


@pytest.mark.parametrize("r_mm", [0.02, 0.05])
def test_a_filleted_corner_deviates_by_the_closed_forms(r_mm):
    r, v = r_mm * MM, 1e-3  # 1 um per sample: the fillet is crossed in 30 to 80 samples
    segments = programmed_path("G64 P0.02\nG1 X2 F60\nY2", CONFIG)
    pos = fillet_samples(r, v)
    line = np.where(pos[:, 1] > 0.0, 3, 2)
    figures = trajectory_figures(trajectory(pos, line), segments)
    (corner,) = figures.corners
    assert corner.angle_rad == pytest.approx(0.5 * math.pi, rel=1e-12)
    # Closest approach to the vertex: |centre - vertex| - r; farthest from the two lines:
    # the fillet's middle, r (1 - 1/sqrt 2) from each.
    assert figures.corner_dev_m[0] == pytest.approx(r * (math.sqrt(2) - 1), rel=1e-3)
    assert figures.path_dev_max_m == pytest.approx(r * (1 - 1 / math.sqrt(2)), rel=1e-3)
    assert figures.corner_speed_m_s[0] == pytest.approx(v, rel=1e-3)
    failures = requirement_failures(figures, chord_tolerance_m=CONFIG.chord_tolerance_m)
    if r * (math.sqrt(2) - 1) <= 20e-6 * (1 + CORNER_RESOLUTION):
        assert failures == []
    else:
        assert failures == [
            "corner at line 2 (90.0 deg): 20.711 um from the vertex (tolerance 20.000 um)"
        ]


def test_corners_skip_stops_and_tangent_joints():
    program = "G64 P0.01\nG1 X10 F600\nG3 X20 Y0 R5\nG1 X30 Y10\nG4 P1\nX40\nG61\nX50 Y5\nX60"
    segments = programmed_path(program, CONFIG)
    assert [s.stops_after for s in segments] == [False, False, True, False, True, True]
    corners = blended_corners(segments)
    # Line -> arc at the top of a semicircle starting upwards: 90 degrees; arc -> line: 45.
    assert [(c.line, round(math.degrees(c.angle_rad), 6)) for c in corners] == [
        (2, 90.0),
        (3, 45.0),
        (6, 26.565051),  # G61 acts from the next move on
    ]
    assert corners[0].tolerance_m == pytest.approx(1e-5)


def test_our_planner_keeps_arcs_within_the_chord_tolerance_and_corners_within_g64():
    config = dataclasses.replace(CONFIG, profile="trapezoid")
    program = "G64 P0.02\nG1 X10 F3000\nG2 X10 Y0 I-10 J0\nG1 X20 Y10\nY0\nM2"
    segments = programmed_path(program, config)
    figures = trajectory_figures(plan_program(program, config), segments)
    assert figures.arc_samples > 500
    # The chord vertices are rounded inwards: the circle is met to within the tolerance but
    # not needlessly finely (the chords' sagitta is 3/4 of it).
    assert 0.8 * config.chord_tolerance_m < figures.arc_dev_max_m <= config.chord_tolerance_m
    assert [round(math.degrees(c.angle_rad)) for c in figures.corners] == [90, 135, 135]
    assert max(figures.corner_dev_m) <= 20e-6 * (1 + CORNER_RESOLUTION)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"t_s": np.array([0.0, 0.001, 0.002, 0.004])}, "t_s: samples must be evenly spaced"),
        ({"pos_m": np.zeros((4, 2))}, "pos_m has 2 axes: the segments have 3"),
    ],
)
def test_bad_trajectories_are_named(change, message):
    base = trajectory(np.zeros((4, 3)))
    fields = {
        "t_s": base.t_s,
        "axes": base.axes,
        "pos_m": base.pos_m,
        "vel_m_s": base.vel_m_s,
        "acc_m_s2": base.acc_m_s2,
        "line": base.line,
        "events": (),
    }
    fields.update(change)
    if fields["pos_m"].shape[1] != 3:
        fields.update(axes=("X", "Y"), vel_m_s=fields["pos_m"], acc_m_s2=fields["pos_m"])
    segments = programmed_path("G1 X1 F100", CONFIG)
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        trajectory_figures(SampledTrajectory(**fields), segments)


def test_too_short_and_empty_inputs_are_named():
    segments = programmed_path("G1 X1 F100", CONFIG)
    with pytest.raises(ValueError, match="len\\(traj\\) = 3: needs at least 4 samples"):
        trajectory_figures(trajectory(np.zeros((3, 3))), segments)
    with pytest.raises(ValueError, match="segments = \\(\\): the program has no moves"):
        trajectory_figures(trajectory(np.zeros((4, 3))), ())


@pytest.mark.parametrize("program", sorted((FIXTURES / "peer").glob("*.ngc")), ids=lambda p: p.name)
def test_corpus_arcs_come_back_whole_and_the_path_is_continuous(program):
    axis_config = load_nc_config(Path(__file__).parent.parent / "config" / "axis_default.yaml")
    segments = programmed_path(program, axis_config)
    blocks = program.read_text().splitlines()
    arc_lines = [n for n, text in enumerate(blocks, 1) if re.search(r"\bG0?[23]\b", text)]
    assert [s.line for s in segments if s.arc is not None] == arc_lines
    for before, after in zip(segments[:-1], segments[1:], strict=True):
        assert before.end_m == after.start_m
    for s in segments:
        if s.arc is not None:  # the arc's own formula meets its programmed end points
            ends = s.point_at(np.array([0.0, 1.0]))
            np.testing.assert_allclose(ends, [s.start_m, s.end_m], rtol=0, atol=1e-9)
