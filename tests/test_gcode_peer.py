"""Two planners on one program: refusals reported, time ratios, JSON-safe summaries."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from feed_twin.gcode import GcodeError, load_nc_config, plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.peer import acceptance_mismatch, measure_side, side_summary, time_ratio

FIXTURES = Path(__file__).parent / "fixtures" / "gcode"
CONFIG = load_nc_config(FIXTURES / "nc_test.yaml")
PROGRAM = "G64 P0.02\nG1 X10 F3000\nG2 X10 Y0 I-10 J0\nG1 X20 Y10\nY0\nM2"


def test_the_same_plan_on_two_sides_agrees_and_a_slower_one_shows_its_ratio():
    segments = programmed_path(PROGRAM, CONFIG)
    trapezoid = dataclasses.replace(CONFIG, profile="trapezoid")
    a = measure_side("a", plan_program(PROGRAM, trapezoid), segments, chord_tolerance_m=2e-6)
    b = measure_side("b", plan_program(PROGRAM, CONFIG), segments, chord_tolerance_m=2e-6)
    assert a.accepted and a.failures == ()
    assert time_ratio(a, a) == 1.0
    # The jerk limit costs time: the S-curve plan is slower than the trapezoidal one.
    assert a.figures is not None and b.figures is not None, "both sides accept the program"
    ratio = time_ratio(b, a)
    assert ratio is not None, "two accepted plans have a time ratio"
    assert ratio == pytest.approx(b.figures.program_time_s / a.figures.program_time_s, rel=1e-12)
    assert ratio > 1.05
    summary = side_summary(a)
    json.dumps(summary, allow_nan=False)
    assert summary["corners"] == 3
    assert summary["arc_dev_max_m"] <= 2e-6


def test_a_program_one_side_refuses_is_reported_with_its_message():
    text = "G1 X10 F3000\nG9 Y10\nG81 X1"
    with pytest.raises(GcodeError) as info:
        plan_program(text, CONFIG)
    ours = measure_side("feed_twin", str(info.value), (), chord_tolerance_m=2e-6)
    segments = programmed_path("G1 X10 F3000", CONFIG)
    theirs = measure_side(
        "other", plan_program("G1 X10 F3000", CONFIG), segments, chord_tolerance_m=2e-6
    )
    assert not ours.accepted and time_ratio(ours, theirs) is None
    assert acceptance_mismatch([theirs, ours]) == (
        "accepted by other only (feed_twin: <text>:3:1: word 'G81': unsupported (canned cycle))"
    )
    assert acceptance_mismatch([theirs, theirs]) is None
    assert acceptance_mismatch([ours, ours]) is None
    assert side_summary(ours) == {"accepted": False, "error": str(info.value)}
