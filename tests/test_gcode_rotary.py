"""Rotary axes A, B, C in the NC: degrees in, radians out, the RS274/NGC feed rule for
rotary-only and mixed moves (closed-form durations), limits and errors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from feed_twin.core.config import ConfigError
from feed_twin.gcode import GcodeError, plan_program
from feed_twin.gcode.config import nc_config_from_mapping
from feed_twin.gcode.interpreter import Interpreter, Move
from feed_twin.gcode.planner import iter_blocks, validate_program

DEG = math.pi / 180.0
LINEAR = [
    {"name": n, "v_max_m_s": 0.5, "rapid_m_s": 0.5, "a_max_m_s2": 3.0, "j_max_m_s3": 60.0,
     "travel_min_m": 0.0, "travel_max_m": 0.8}
    for n in "XYZ"
]  # fmt: skip
B_AXIS = {"name": "B", "v_max_deg_s": 360.0, "rapid_deg_s": 360.0, "a_max_deg_s2": 600.0,
          "j_max_deg_s3": 12000.0, "travel_min_deg": -120.0, "travel_max_deg": 120.0}  # fmt: skip


def nc(rotary=(B_AXIS,), profile="trapezoid", **changes):
    data = {
        "twin_axis": "X",
        "profile": profile,
        "path_tolerance_m": 1e-5,
        "chord_tolerance_m": 2e-6,
        "arc_radius_tolerance_m": 1e-5,
        "start_position_m": [0.4, 0.4, 0.4],
        "axes": LINEAR,
        "work_offsets_m": {f"G5{k}": [0.0, 0.0, 0.0] for k in range(4, 10)},
        "rotary_axes": list(rotary),
        **changes,
    }
    return nc_config_from_mapping(data, source="<nc>")


def move_time(traj) -> float:
    """[s] from the start to the last sample whose position differs from the end."""
    moving = np.flatnonzero(np.any(np.abs(traj.pos_m - traj.pos_m[-1]) > 1e-12, axis=1))
    return float(traj.t_s[moving[-1]])


def test_rotary_axis_is_planned_in_radians_after_the_linear_axes():
    config = nc()
    assert config.axis_names == ("X", "Y", "Z", "B")
    assert config.v_max[3] == pytest.approx(2 * math.pi)
    assert config.start_position == (0.4, 0.4, 0.4, 0.0)
    traj = plan_program("G90 G1 B45 F3600\n", config)
    assert traj.axis("B")[0][-1] == pytest.approx(45 * DEG, abs=1e-12)
    assert np.all(traj.pos_m[:, :3] == 0.4)


def test_rotary_only_move_runs_at_f_degrees_per_minute():
    # trapezoid: T = theta/omega + omega/alpha = 90/60 + 60/600 s
    traj = plan_program("G1 B90 F3600\n", nc())
    assert move_time(traj) == pytest.approx(1.6, abs=1.5e-3)
    assert np.max(traj.axis("B")[1]) == pytest.approx(60 * DEG, rel=1e-9)


def test_inch_mode_leaves_rotary_words_and_their_feed_in_degrees():
    traj = plan_program("G20 G1 B30 F600\n", nc())  # 10 deg/s: 3 s + 10/600 s
    assert traj.axis("B")[0][-1] == pytest.approx(30 * DEG, abs=1e-12)
    assert move_time(traj) == pytest.approx(3.0 + 10 / 600, abs=1.5e-3)


def test_mixed_move_feed_applies_to_the_linear_path_with_the_rotary_axis_in_step():
    # RS274/NGC: 100 mm of X at 6000 mm/min; B (90 deg) arrives with X, at 90 deg/s. The
    # ramps take the longer of X's (0.1 m/s at 3 m/s^2) and B's (90 deg/s at 600 deg/s^2):
    # T = 0.1/0.1 + max(0.1/3, 90/600) s.
    traj = plan_program("G91 G1 X100 B90 F6000\n", nc())
    assert move_time(traj) == pytest.approx(1.0 + max(0.1 / 3.0, 90 / 600), abs=1.5e-3)
    x, vx, _ = traj.axis("X")
    b, vb, _ = traj.axis("B")
    assert np.max(vx) == pytest.approx(0.1, rel=1e-9)
    # synchronised: B covers the same share of its move as X at every sample
    assert np.allclose((b - 0.0) / (90 * DEG), (x - 0.4) / 0.1, atol=1e-9)


def test_mixed_move_is_limited_by_the_rotary_axis_when_it_is_the_slower_one():
    # B needs 90 deg at 360 deg/s max; 1 mm of X at 6000 mm/min would take 10 ms: B's
    # velocity (then acceleration) limit sets the time: T = 0.25 + 360/600 s... but the
    # ramp alone needs 2 sqrt(theta/alpha) = 0.775 s < 0.25 + 0.6, so a triangle profile.
    traj = plan_program("G91 G1 X1 B90 F6000\n", nc())
    assert move_time(traj) == pytest.approx(2 * math.sqrt(90 / 600), abs=1.5e-3)


def test_sinumerik_opening_g1_b0_runs_without_a_feed():
    traj = plan_program("G1 B0\nG1 X500 F1000\n", nc(profile="jerk"))
    assert traj.axis("X")[0][-1] == pytest.approx(0.5, abs=1e-12)
    with pytest.raises(GcodeError, match=r"<text>:1:1: word 'G1': feed move before any F word"):
        plan_program("G1 B10\n", nc())


def test_rotary_word_on_a_machine_without_it_is_refused_before_planning():
    with pytest.raises(GcodeError, match=r"<text>:2:4: word 'B0': unknown word \(axis B is not"):
        validate_program("G1 X500 F100\nG1 B0\n", nc(rotary=()))


def test_rotary_travel_is_checked_in_degrees():
    with pytest.raises(
        GcodeError, match=r"B = 130 deg \(machine\) is outside the travel \[-120, 120\] deg"
    ):
        plan_program("G1 B130 F100\n", nc())


def test_arc_moves_the_rotary_axis_linearly_along_the_sweep():
    config = dataclasses.replace(nc(), chord_tolerance_m=1e-4)
    file, blocks = iter_blocks("G17 G90 G2 X500 Y400 I50 J0 B20 F1000\n", config)
    moves = [m for m in Interpreter(config, file=file).run(blocks) if type(m) is Move]
    assert len(moves) > 10
    assert moves[-1].end_m[3] == pytest.approx(20 * DEG)
    sweep = np.array([math.atan2(m.end_m[1] - 0.4, m.end_m[0] - 0.45) for m in moves])
    share = (math.pi - np.mod(sweep, 2 * math.pi)) / math.pi  # clockwise from 180 degrees
    share[-1] = 1.0
    assert np.allclose([m.end_m[3] for m in moves], 20 * DEG * share, atol=1e-9)
    # every chord: F along its XY length, so feed_m_s is F times |all| / |XY|
    start = np.array(config.start_position)
    for m in moves:
        d = np.array(m.end_m) - start
        expected = (1000e-3 / 60) * np.linalg.norm(d) / np.linalg.norm(d[:3])
        assert m.feed_m_s == pytest.approx(expected, rel=1e-12)
        start = np.array(m.end_m)


def test_rotary_axis_config_errors_name_the_field():
    with pytest.raises(
        ConfigError, match=r"<nc>: nc.rotary_axes\[0\].name = 'Q': must be one of A, B, C"
    ):
        nc(rotary=({**B_AXIS, "name": "Q"},))
    with pytest.raises(
        ConfigError, match=r"nc.rotary_axes\[0\].start_deg = 150.0: outside the travel"
    ):
        nc(rotary=({**B_AXIS, "start_deg": 150.0},))
    with pytest.raises(ConfigError, match=r"rotary_axes = \('B', 'B'\): axis names must be unique"):
        nc(rotary=(B_AXIS, B_AXIS))


def test_plan_cli_reads_a_machine_config_and_names_rotary_columns_in_radians(tmp_path, capsys):
    from pathlib import Path

    from feed_twin.cli import main as cli_main

    machine = Path(__file__).resolve().parents[1] / "config" / "machine_default.yaml"
    program = tmp_path / "p.ngc"
    program.write_text("G1 B0\nG91 G1 X30 B40 F3000\nM2\n")
    out = tmp_path / "p.csv"
    assert cli_main(["plan", str(program), "--config", str(machine), "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header[-4:] == ["b_rad", "vb_rad_s", "ab_rad_s2", "line"]
    last = np.array(out.read_text().splitlines()[-1].split(","), dtype=float)
    assert last[header.index("b_rad")] == pytest.approx(40 * DEG)
    # the path length is the tool's: X alone, 30 mm
    assert "path length  30.000 mm" in capsys.readouterr().out
