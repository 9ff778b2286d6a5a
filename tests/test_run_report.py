"""The run report (feed_twin.nodeset.run_report): units, no raw values, the same object in JSON."""

from __future__ import annotations

import json
import math
import re

import pytest

from feed_twin.nodeset.pacing import pacing_report
from feed_twin.nodeset.run_report import RunReport, RunTiming
from feed_twin.nodeset.summary import json_line

# a raw value in text: nan, None, inf, a repr, or a float with more than 6 decimals
RAW = re.compile(r"\b(nan|NaN|None|inf)\b|<\w|\d\.\d{7,}")


INTRUDER = "node '/intruder' (publisher gid 01.0f)"
FOREIGN = {"/cnc/x/command": {"messages": 3, "reasons": {"bad tag": 3}, "publishers": [INTRUDER]}}


def _paced() -> RunTiming:
    late = [0.0001, 0.0002, 0.0004, 0.0031]  # [s]; one over the 1 ms period
    return RunTiming.from_report(
        pacing_report(steps=4, period_s=1e-3, wall_s=0.004, lateness_s=late)
    )


def test_timing_from_a_paced_record_is_si_and_counts_the_missed_step():
    timing = _paced()
    assert timing.steps == 4 and timing.missed_steps == 1
    assert timing.sim_time_s == pytest.approx(0.004) and timing.realtime_factor == pytest.approx(
        1.0
    )
    assert timing.lateness_max_s == pytest.approx(0.0031)
    assert timing.lateness_p50_s == pytest.approx(0.0003)  # median of 0.2 and 0.4 ms
    # back to the record's keys and units for --json
    assert timing.as_dict()["timing_lateness_max_ms"] == pytest.approx(3.1)


def test_a_record_without_samples_gives_none_never_nan():
    timing = RunTiming.from_report(pacing_report(steps=0, period_s=1e-3, wall_s=0.0, lateness_s=[]))
    assert timing.realtime_factor is None and timing.lateness_p99_s is None
    assert timing.missed_steps == 0


def test_every_mode_formats_the_same_fields_with_units_and_no_raw_values():
    unpaced = RunTiming.from_report(pacing_report(steps=2000, period_s=1e-3, wall_s=0.25))
    reports = [
        RunReport(mode="axis nodes", exit_code=0, timing=unpaced, samples=2000, bag="bags/a"),
        RunReport(
            mode="axis shadow",
            exit_code=3,
            reason="node gone",
            timing=_paced(),
            figure_lines=("peak current:          1.00 A",),
            foreign_messages={
                "/cnc/x/state": {
                    "messages": 12,
                    "reasons": {"unsigned": 12},
                    "publishers": [INTRUDER],
                }
            },  # fmt: skip
            ros_domain=17,
            bag_recovered_messages=40,
            bag="bags/b",
            slow_nodes={"/cnc/x/gcode": 2.5, "/cnc/x/controller": 0.91},
        ),
        RunReport(mode="axis nodes", exit_code=130),
    ]
    labels = None
    for report in reports:
        text = report.format()
        assert not RAW.search(text), text
        found = [line.split(":")[0] for line in text.splitlines() if not line.startswith("peak")]
        labels = labels or found
        assert found == labels  # the same fields in every mode
    assert "8x real time, 2.000 s simulated in 0.250 s wall time" in reports[0].format()
    assert "not paced by the wall clock" in reports[0].format()
    shadow = reports[1].format()
    assert "p50 0.300 ms, p99 3.019 ms, max 3.100 ms; missed steps 1" in shadow
    assert f"/cnc/x/state: 12 dropped, from {INTRUDER}" in shadow
    assert "ROS domain:           17" in shadow
    assert (
        "slow nodes:           /cnc/x/controller 0.91 s, /cnc/x/gcode 2.50 s without progress "
        "(not gone: the run went on)"
    ) in shadow
    assert "slow nodes:           none" in reports[0].format()
    assert "bags/b (incomplete: 40 messages recovered)" in shadow
    assert "interrupted" in reports[2].format() and reports[2].interrupted


def test_json_is_the_same_object_strict_and_keeps_the_earlier_keys():
    report = RunReport(
        mode="axis nodes",
        exit_code=0,
        timing=_paced(),
        figures={"cycle_time_s": 1.5, "current_peak_A": math.nan},
        foreign_messages=FOREIGN,
    )
    record = json.loads(json_line(report.as_dict()))
    for key in ("exit_code", "interrupted", "bag", "rrd", "logs", "reason", "timing_steps"):
        assert key in record
    assert record["current_peak_A"] is None  # NaN is null in strict JSON
    assert record["foreign_messages"] == FOREIGN
    assert record["timing_missed_steps"] == 1 and record["mode"] == "axis nodes"
    assert record["slow_nodes"] == {}
    slow = RunReport(mode="axis nodes", exit_code=0, slow_nodes={"/cnc/x/sim": 1.25})
    assert json.loads(json_line(slow.as_dict()))["slow_nodes"] == {"/cnc/x/sim": 1.25}


def test_the_report_is_frozen_with_its_mappings():
    report = RunReport(mode="axis nodes", exit_code=0, foreign_messages=FOREIGN)
    with pytest.raises(TypeError):
        report.foreign_messages["/a/b/state"] = {}  # type: ignore[index]
    with pytest.raises(TypeError):
        report.foreign_messages["/cnc/x/command"]["messages"] = 2  # type: ignore[index]
    with pytest.raises(ValueError, match="mode = '': must name the run's mode"):
        RunReport(mode="", exit_code=0)


def test_a_figure_the_run_has_not_is_said_in_words():
    from feed_twin.nodeset.run_report import shown
    from feed_twin.nodeset.summary import RunSummary

    assert shown(math.nan, "A") == "not measured" and shown(None, "ms") == "not measured"
    assert shown(1.25e-5, "um", scale=1e6, digits=2) == "12.50 um"
    # a LinuxCNC servo or the EMPS bench reports no current: no "nan A" in the axis figures
    summary = RunSummary(cycle_time_s=1.0, following_error_max_m=2e-5, following_error_rms_m=1e-5,
                         current_peak_A=math.nan, velocity_peak_m_s=0.05, sim_time_s=1.2,
                         samples=1200)  # fmt: skip
    text = summary.format()
    assert "peak current:          none (no current recorded)" in text
    assert RAW.search(text) is None, text


def test_per_axis_dashboards_and_an_in_process_run_are_said_in_words():
    report = RunReport(
        mode="machine LinuxCNC shadow", exit_code=0, rrd_per_axis={"x": "b_x.rrd", "y": None}
    )
    assert "rerun:                x: b_x.rrd, y: none" in report.format()
    assert report.as_dict()["rrd_per_axis"] == {"x": "b_x.rrd", "y": None}
    in_process = RunReport(mode="machine in-process", exit_code=0, uses_ros=False)
    assert "ROS domain:           none (in-process, no ROS)" in in_process.format()
    assert in_process.as_dict()["ros_domain"] is None
