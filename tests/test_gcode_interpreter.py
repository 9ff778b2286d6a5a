"""Modal interpreter: G-code facts -> machine positions in SI, arcs as chords, events, errors."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode import GcodeError, load_nc_config, plan_program
from feed_twin.gcode.codes import (
    CUTTER_COMPENSATION,
    FEED_MODE,
    GROUP_OF,
    NON_MODAL,
    TOOL_LENGTH_OFFSET,
    g_code_name,
)
from feed_twin.gcode.interpreter import MODE_ACTIONS, Event, Interpreter, Move, Stop
from feed_twin.gcode.planner import iter_blocks, validate_program

FIXTURES = Path(__file__).parent / "fixtures" / "gcode"
CONFIG = load_nc_config(FIXTURES / "nc_test.yaml")
MM = 1e-3


def run(text: str, config=CONFIG):
    file, blocks = iter_blocks(text, config)
    return list(Interpreter(config, file=file).run(blocks))


def moves(text: str, config=CONFIG) -> list[Move]:
    items = run(text, config)
    found = [item for item in items if isinstance(item, Move)]
    assert len(found) == len(items), f"not only moves: {items}"
    return found


def ends(text: str, config=CONFIG) -> np.ndarray:
    return np.array([item.end_m for item in run(text, config) if isinstance(item, Move)])


def test_absolute_incremental_and_metric():
    got = ends("G21 G90 G0 X10 Y20\nG91 G1 X5 Z-2 F100\nG90 X1")
    np.testing.assert_allclose(
        got, [[0.01, 0.02, 0.0], [0.015, 0.02, -0.002], [0.001, 0.02, -0.002]]
    )


def test_inch_units_scale_geometry_and_feed():
    items = moves("G20 G1 X1 Y-0.5 F10")
    np.testing.assert_allclose(items[0].end_m, [0.0254, -0.0127, 0.0], rtol=1e-15)
    assert items[0].feed_m_s == pytest.approx(10 * 0.0254 / 60, rel=1e-15)


def test_sinumerik_g70_keeps_feed_metric_and_g700_switches_feed_too():
    g70 = moves("G70 G1 X1 F600")[0]
    assert g70.end_m[0] == pytest.approx(0.0254) and g70.feed_m_s == pytest.approx(0.01)
    g700 = moves("G700 G1 X1 F60")[0]
    assert g700.feed_m_s == pytest.approx(60 * 0.0254 / 60)
    back = moves("G700 G1 X1 F60\nG710 X10 F600")[1]
    assert back.end_m[0] == pytest.approx(0.01) and back.feed_m_s == pytest.approx(0.01)


def test_work_offsets_g53_and_g92():
    got = ends("G55 G0 X0 Y0\nX10\nG54 X0\nG53 G0 Z20\nG59 G0 X0 Y0 Z0")
    np.testing.assert_allclose(
        got,
        [[0.1, 0.2, 0.0], [0.11, 0.2, 0.0], [0.0, 0.2, 0.0], [0.0, 0.2, 0.02], [-0.2, -0.2, -0.1]],
        atol=1e-15,
    )
    got = ends("G0 X10\nG92 X0\nG0 X5\nG92.1\nG0 X5")
    np.testing.assert_allclose(got[:, 0], [0.01, 0.015, 0.005], atol=1e-15)


def _arc_points(text: str):
    items = [i for i in run(text) if isinstance(i, Move)]
    return np.array([i.end_m for i in items]), items


def test_full_circle_chords_lie_on_the_circle_within_the_chord_tolerance():
    points, items = _arc_points("G17 G1 X10 F1000\nG2 X10 Y0 I-10 J0")
    arc = points[1:]
    r = np.hypot(arc[:, 0], arc[:, 1])
    np.testing.assert_allclose(r, 0.01, rtol=1e-12)
    theta = np.unwrap(np.arctan2(arc[:, 1], arc[:, 0]))
    assert theta[-1] - 0.0 == pytest.approx(-2 * np.pi, abs=1e-12)  # clockwise, one turn
    step = np.abs(np.diff(np.concatenate(([0.0], theta))))
    sagitta = 0.01 * (1 - np.cos(step / 2))
    assert sagitta.max() <= CONFIG.chord_tolerance_m
    assert sagitta.max() > 0.5 * CONFIG.chord_tolerance_m  # not needlessly fine
    assert all(i.line == 2 for i in items[1:])


@pytest.mark.parametrize(
    ("program", "first", "second", "expect_mid"),
    [
        # G2 is clockwise seen from the positive normal axis of each plane.
        ("G17 G1 X0 Y10 F100\nG2 X0 Y-10 I0 J-10", 0, 1, (10, 0)),
        ("G18 G1 X10 Z0 F100\nG2 X-10 Z0 I-10 K0", 2, 0, (10, 0)),
        ("G19 G1 Y0 Z10 F100\nG2 Y0 Z-10 J0 K-10", 1, 2, (10, 0)),
        ("G17 G1 X0 Y10 F100\nG3 X0 Y-10 I0 J-10", 0, 1, (-10, 0)),
    ],
)
def test_arc_direction_in_each_plane(program, first, second, expect_mid):
    points, _ = _arc_points(program)
    arc = points[1:]
    mid = arc[len(arc) // 2 - 1 : len(arc) // 2 + 1].mean(axis=0)
    assert mid[first] / MM == pytest.approx(expect_mid[0], abs=0.01)
    assert mid[second] / MM == pytest.approx(expect_mid[1], abs=0.01)


def test_r_form_short_and_long_arcs():
    short, _ = _arc_points("G2 X10 Y10 R10 F100")
    np.testing.assert_allclose(np.hypot(short[:, 0] - 0.01, short[:, 1]), 0.01, rtol=1e-12)
    long_, _ = _arc_points("G2 X10 Y10 R-10 F100")
    np.testing.assert_allclose(np.hypot(long_[:, 0], long_[:, 1] - 0.01), 0.01, rtol=1e-12)
    assert len(long_) > 2.5 * len(short)  # 270 degrees against 90


def test_absolute_arc_centres_g90_1():
    points, _ = _arc_points("G55 G0 X0 Y0\nG90.1 G3 X-10 Y10 I-10 J0 F100")
    centre = np.array([0.1 - 0.01, 0.2])
    np.testing.assert_allclose(np.hypot(*(points[1:, :2] - centre).T), 0.01, rtol=1e-12)


def test_helix_with_turns_rises_in_proportion_to_angle():
    points, _ = _arc_points("G1 X10 F100\nG3 X10 Y0 Z-6 I-10 P3")
    arc = points[1:]
    theta = np.unwrap(np.arctan2(arc[:, 1], arc[:, 0]))
    assert theta[-1] == pytest.approx(6 * np.pi, abs=1e-9)
    np.testing.assert_allclose(arc[:, 2], -0.006 * theta / (6 * np.pi), atol=1e-15)


def test_events_in_block_order_and_stops():
    items = run('T3 M6\nS9000 M3\nG4 P0.25\nM8\nT="FACE_MILL"\nM0\nM5 M9\nM30\nG0 X5')
    kinds = [(i.kind, i.value, i.line) for i in items if isinstance(i, Event)]
    assert kinds == [
        ("tool_select", 3.0, 1),
        ("tool_change", 3.0, 1),
        ("spindle_speed", 9000.0, 2),
        ("spindle_cw", 9000.0, 2),
        ("dwell", 0.25, 3),
        ("coolant_on", 8.0, 4),
        ("warning", 0.0, 5),
        ("pause", 0.0, 6),
        ("spindle_stop", 0.0, 7),
        ("coolant_off", 0.0, 7),
        ("end", 30.0, 8),
    ]
    warning = [i for i in items if isinstance(i, Event) and i.kind == "warning"][0]
    assert warning.text == 'line 5: controller-specific word T="FACE_MILL" ignored'
    assert [i.dwell_s for i in items if isinstance(i, Stop)] == [0.25]
    assert not any(isinstance(i, Move) for i in items)  # nothing runs after M30


def test_dwell_units_and_fanuc_x_dwell():
    assert [i.dwell_s for i in run("G4 P1.5") if isinstance(i, Stop)] == [1.5]
    fanuc = dataclasses.replace(CONFIG, dwell_p_unit="ms")
    assert [i.dwell_s for i in run("G4 P1500", fanuc) if isinstance(i, Stop)] == [1.5]
    assert [i.dwell_s for i in run("G4 X2") if isinstance(i, Stop)] == [2.0]


def test_path_control_modes_and_tolerance():
    items = moves("G1 X1 F100\nG61 X2\nG64 P0.005 X3\nX4 G9\nG64 X5\nG64 P0.003 Q0.001 X6")
    assert [i.exact_stop for i in items] == [False, True, False, True, False, False]
    assert [i.tolerance_m for i in items] == pytest.approx(
        [2e-5, 2e-5, 5e-6, 5e-6, CONFIG.path_tolerance_m, 3e-6]
    )


def test_comments_case_and_line_numbers_are_ignored():
    got = ends("%\nn10 g0 x1 (move) ; note\n/ G0 X99\nN20 G0 Y2\n%")
    np.testing.assert_allclose(got, [[0.001, 0.0, 0.0], [0.001, 0.002, 0.0]])


@pytest.mark.parametrize(
    ("program", "message"),
    [
        ("G1 X1 F100 Q2", "<text>:1:12: word 'Q2': Q word without G64 P"),
        ("G64 Q0.01", "<text>:1:5: word 'Q0.01': G64 Q needs a P tolerance in the same block"),
        ("G64 P0.01 Q-1", "<text>:1:11: word 'Q-1': G64 Q tolerance must be >= 0"),
        ("G1 A5 F100", "<text>:1:4: word 'A5': unknown word (axis A is not configured)"),
        ("O100 G0 X1", "<text>:1:1: word 'O100': unknown word (O-word subroutines are not"),
        ("G93 G1 X1 F2", "<text>:1:1: word 'G93': unsupported mode (inverse-time feed)"),
        ("G95 G1 X1 F2", "<text>:1:1: word 'G95': unsupported mode (feed per revolution)"),
        ("G41 G1 X1 F2", "<text>:1:1: word 'G41': unsupported mode (cutter radius compensation)"),
        ("G81 X1 Z-1 R1", "<text>:1:1: word 'G81': unsupported (canned cycle)"),
        ("G12 X1", "<text>:1:1: word 'G12': unknown G-code"),
        ("M98 P100", "<text>:1:1: word 'M98': unsupported M-code"),
        ("G0 X0\nG1 X5", "<text>:2:1: word 'G1': feed move before any F word"),
        ("G1 F100\nG0 X1\nG2 X2 Y0", "<text>:3:1: word 'G2': arc without a centre (I/J/K) or"),
        ("G1 X10 F100\nG2 X-10 Y1 I-10", "<text>:2:12: word 'I-10': start radius 10 mm and end"),
        ("G2 X10 Y0 K5 F100", "<text>:1:11: word 'K5': not an arc-centre word in the G17 (XY)"),
        ("G2 X0 Y0 R5 F100", "<text>:1:10: word 'R5': R-form arc with equal start and end"),
        ("G2 X10 Y0 R4 F100", "<text>:1:11: word 'R4': radius 4 mm is smaller than half the"),
        ("G2 X10 Y0 R5 I5 F100", "<text>:1:11: word 'R5': arc with both R and I/J/K"),
        ("G0 X600", "<text>:1:4: word 'X600': X = 600 mm (machine) is outside the travel"),
        (
            "G1 X0 F100\nG2 X0 Y0 I290",
            "<text>:2:1: word 'G2': X = 501.069 mm (machine) is outside the travel [-500, 500]",
        ),
        ("G0 G1 X1 F1", "<text>:1:4: word 'G1': conflicts with G0 (both in the motion group)"),
        ("G0 X1 X2", "<text>:1:7: word 'X2': repeats X1 in the same block"),
        ("X1", "<text>:1:1: word 'X1': axis word without a motion mode (G0, G1, G2, G3)"),
        ("G91 G53 G0 X1", "<text>:1:5: word 'G53': G53 is not allowed in incremental mode"),
        ("G0 X1 I2", "<text>:1:7: word 'I2': arc word without an arc move"),
        ("G1 X1 F0", "<text>:1:7: word 'F0': feed must be > 0"),
        ("G4", "<text>:1:1: word 'G4': G4 dwell needs a P (or X) word"),
        ("G92", "<text>:1:1: word 'G92': G92 needs at least one axis word"),
        ("T1.5", "<text>:1:1: word 'T1.5': tool number must be a whole number >= 0"),
        ("G1.55 X1", "<text>:1:1: word 'G1.55': unknown G-code"),
        ("S-100 M3", "<text>:1:1: word 'S-100': spindle speed must be >= 0"),
        ("G64 P0", "<text>:1:5: word 'P0': G64 P tolerance must be > 0"),
        ("G53 G2 X1 Y0 R1 F100", "<text>:1:1: word 'G53': G53 needs G0 or G1"),
        ("G53", "<text>:1:1: word 'G53': G53 without axis words"),
        ("G1 X1 F100 P2", "<text>:1:12: word 'P2': P word without G4, G64 or an arc"),
        ("G4 G1 P1", "<text>:1:1: word 'G4': G4 cannot share a block with a motion code"),
        ("G4 P-1", "<text>:1:4: word 'P-1': dwell time must be >= 0"),
        ("G2 X0 Y0 I5 P1.5 F100", "<text>:1:13: word 'P1.5': arc turn count P must be a whole"),
        ("G2 X5 Y0 I0 J0 F100", "<text>:1:10: word 'I0': arc centre coincides with the start"),
    ],
)
def test_bad_programs_name_file_line_column_and_word(program, message):
    with pytest.raises(GcodeError) as info:
        run(program)
    assert str(info.value).startswith(message)


def test_errors_carry_their_parts():
    with pytest.raises(GcodeError) as info:
        run("G0 X1\n  G93 G1 X2 F1")
    err = info.value
    assert (err.file, err.line, err.column, err.word) == ("<text>", 2, 3, "G93")
    assert err.reason == "unsupported mode (inverse-time feed)"
    assert isinstance(err, ValueError)


def test_validation_covers_the_whole_program_and_empty_files(tmp_path):
    program = "\n".join(["G1 X1 F100"] * 50 + ["G1 X900"])
    with pytest.raises(GcodeError, match=r"^<text>:51:4: word 'X900'"):
        validate_program(program, CONFIG)
    empty = tmp_path / "empty.ngc"
    empty.write_text("%\n(nothing)\n\n%\n")
    with pytest.raises(GcodeError, match=r"empty.ngc: the program is empty \(no G-code blocks\)"):
        validate_program(empty, CONFIG)
    assert validate_program("G0 X1\nG1 Y1 F100\nG2 X2 Y0 R1", CONFIG) > 2
    with pytest.raises(GcodeError, match=r"<text>: the program is empty \(no G-code blocks\)"):
        plan_program("(only a comment)\n%\n", CONFIG)


def test_fast_path_for_plain_blocks_matches_the_general_path():
    rng = np.random.default_rng(5)
    # Absolute millimetres, and an incremental walk in inches that stays within the travel.
    for mode, span in (("G90", 50.0), ("G91 G20", 0.4)):
        values = rng.uniform([-span, -span, 100], [span, span, 5000], (200, 3))
        body = [
            f"{'G0' if k % 7 == 0 else 'G1'} X{x:.3f} Y{y:.3f}" + (f" F{f:.0f}" if k % 5 else "")
            for k, (x, y, f) in enumerate(values)
        ]
        plain = f"{mode} F1000\n" + "\n".join(body)
        # G94 (already active) sends every block through the general path.
        general = f"{mode} F1000\n" + "\n".join(line + " G94" for line in body)
        items = run(plain)
        assert len(items) > 150 and items == run(general)


def test_percent_delimited_program_ends_at_the_second_percent():
    assert len(ends("%\nG0 X1\n%\nG0 X2 Q7 (not read)")) == 1
    # Without a leading '%', a '%' line is only skipped.
    assert len(ends("G0 X1\n%\nG0 X2")) == 2


@pytest.mark.parametrize(
    ("value", "name"),
    [(0.0, "G0"), (1.0, "G1"), (90.1, "G90.1"), (64.0, "G64"), (700.0, "G700"), (38.2, "G38.2")],
)
def test_g_words_are_named_by_their_number_in_tenths(value, name):
    assert g_code_name(value) == name


def test_g_words_finer_than_tenths_have_no_name_and_are_unknown():
    assert g_code_name(90.15) is None
    with pytest.raises(GcodeError, match=r"<text>:1:1: word 'G90.15': unknown G-code"):
        run("G90.15 X1")


def test_every_stateful_modal_code_has_an_action_and_every_action_a_known_code():
    stateless = {FEED_MODE, CUTTER_COMPENSATION, TOOL_LENGTH_OFFSET, NON_MODAL}
    stateful = {name for name, group in GROUP_OF.items() if group not in stateless}
    assert stateful == set(MODE_ACTIONS)
