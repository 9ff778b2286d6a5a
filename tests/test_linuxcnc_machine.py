"""The LinuxCNC machine files from the nc: section, and the recorded rows in SI units."""

from __future__ import annotations

import configparser
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode.config import load_nc_config
from feed_twin.linuxcnc.machine import (
    check_machine,
    machine_files,
    machine_for_config,
    servo_for_axis,
)
from feed_twin.linuxcnc.samples import ROW_HEADER, rows_to_trace, sample_layout

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "axis_default.yaml"


def _ini(files: dict[str, str]) -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = lambda optionstr: optionstr  # keys keep their case, as LinuxCNC's
    parser.read_string(files["machine.ini"])
    return parser


def test_ini_limits_come_from_the_nc_section_in_millimetres() -> None:
    nc, servo = machine_for_config(CONFIG)
    ini = _ini(machine_files(nc, servo))
    for joint, axis in enumerate(nc.axes):
        section = ini[f"JOINT_{joint}"]
        assert float(section["MAX_VELOCITY"]) == pytest.approx(axis.rapid_m_s * 1e3)
        assert float(section["MAX_ACCELERATION"]) == pytest.approx(axis.a_max_m_s2 * 1e3)
        assert float(section["MIN_LIMIT"]) == pytest.approx(axis.travel_min_m * 1e3)
        assert float(section["MAX_LIMIT"]) == pytest.approx(axis.travel_max_m * 1e3)
        assert float(section["HOME"]) == pytest.approx(nc.start_position_m[joint] * 1e3)
        assert float(section["HOME_SEARCH_VEL"]) == 0.0  # homing without motion
        assert float(section["P"]) == pytest.approx(30.0)  # Kv of axis_default's controller
        assert float(section["FERROR"]) == pytest.approx(2.0)  # its 2 mm limit
        assert float(ini[f"AXIS_{axis.name}"]["MAX_LIMIT"]) == pytest.approx(
            axis.travel_max_m * 1e3
        )
    assert ini["EMCMOT"]["SERVO_PERIOD"] == "1000000"
    assert ini["TRAJ"]["LINEAR_UNITS"] == "mm"


def test_work_offsets_are_the_interpreters_parameters() -> None:
    nc, servo = machine_for_config(CONFIG)
    params = dict(
        (int(n), float(v))
        for n, v in (line.split() for line in machine_files(nc, servo)["machine.var"].splitlines())
    )
    # rs274ngc: G54 X/Y/Z are 5221-5223, G55 5241-5243 ... (mm), 5220 the active system
    assert params[5220] == 1.0
    assert [params[5241], params[5242], params[5243]] == pytest.approx([200.0, 100.0, 300.0])
    assert [params[5321], params[5322], params[5323]] == pytest.approx([0.0, 0.0, 0.0])


def test_committed_machine_matches_axis_default() -> None:
    nc, servo = machine_for_config(CONFIG)
    assert check_machine(REPO / "config" / "linuxcnc", nc, servo) == []
    changed = dataclasses.replace(servo, Kv_1_s=20.0)
    assert check_machine(REPO / "config" / "linuxcnc", nc, changed) == [
        str(REPO / "config" / "linuxcnc" / "machine.ini")
    ]


def test_the_drive_lag_is_sampled_exactly() -> None:
    servo = servo_for_axis(None)
    # a step through the lowpass reaches 1 - exp(-t/tau) after t = n periods
    y = 0.0
    for _ in range(5):
        y += servo.lowpass_gain * (1.0 - y)
    assert y == pytest.approx(1.0 - np.exp(-5e-3 / servo.drive_lag_s), rel=1e-12)


def test_machine_needs_exactly_x_y_z() -> None:
    nc = load_nc_config(CONFIG)
    u_axis = dataclasses.replace(nc.axes[0], name="U")
    offsets = {
        code: (*getattr(nc.work_offsets_m, code), 0.0)
        for code in ("G54", "G55", "G56", "G57", "G58", "G59")
    }
    four = dataclasses.replace(
        nc,
        axes=(*nc.axes, u_axis),
        start_position_m=(*nc.start_position_m, 0.0),
        work_offsets_m=dataclasses.replace(nc.work_offsets_m, **offsets),
    )
    with pytest.raises(ValueError, match=r"nc.axes = \['X', 'Y', 'Z', 'U'\]: .*exactly the axes"):
        machine_files(four, servo_for_axis(None))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("Kv_1_s", -1.0, "Kv_1_s = -1.0: must be > 0"),
        ("servo_period_s", 0.5, r"servo_period_s = 0.5: must lie in \[0.0001, 0.01\]"),
        ("min_ferror_m", 1.0, "min_ferror_m = 1.0: must be <= ferror_m = 0.002"),
        ("sample_depth", 10, r"sample_depth = 10: must lie in \[1000, 1000000\]"),
    ],
)
def test_servo_parameters_are_checked(field: str, value: float, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(servo_for_axis(None), **{field: value})


def _rows(ticks: list[int]) -> np.ndarray:
    layout = sample_layout()
    rows = np.zeros((len(ticks), layout.row_width))
    for i, tick in enumerate(ticks):
        values = rows[i, len(ROW_HEADER) :]
        values[layout.index("tick")] = tick
        values[layout.index("tick_time_s")] = 100.0 + tick * 1e-3
        values[layout.index("x.pos_cmd")] = 400.0 + tick  # mm
        values[layout.index("y.vel_cmd")] = 50.0  # mm/s
        values[layout.index("z.acc_cmd")] = -2500.0  # mm/s^2
        values[layout.index("x.pid_output")] = 12.5  # mm/s
        values[layout.index("program_line")] = 7
        rows[i, 0] = 100.0 + tick * 1e-3 + 2e-4
    return rows


def test_rows_become_si_per_tick_arrays() -> None:
    trace = rows_to_trace(_rows([5, 6, 7, 8]), sample_layout(), period_s=1e-3)
    assert trace.tick.tolist() == [0, 1, 2, 3]
    assert trace.t_s == pytest.approx([0.0, 1e-3, 2e-3, 3e-3])  # tick x period, not the clock
    assert trace.pos_cmd_m[:, 0] == pytest.approx([0.405, 0.406, 0.407, 0.408])
    assert trace.vel_cmd_m_s[:, 1] == pytest.approx([0.05] * 4)
    assert trace.acc_cmd_m_s2[:, 2] == pytest.approx([-2.5] * 4)
    assert trace.pid_output_m_s[:, 0] == pytest.approx([0.0125] * 4)
    assert trace.reader_latency_s == pytest.approx([2e-4] * 4)
    assert trace.program_line.tolist() == [7] * 4
    assert trace.samples_lost == 0


def test_gaps_in_the_tick_count_are_lost_samples() -> None:
    trace = rows_to_trace(_rows([0, 1, 4, 5, 9]), sample_layout(), period_s=1e-3)
    assert trace.samples == 5
    assert trace.samples_lost == 5  # ticks 2, 3, 6, 7, 8
    assert trace.t_s[-1] == pytest.approx(9e-3)
    with pytest.raises(ValueError, match="tick indices are not increasing"):
        rows_to_trace(_rows([0, 2, 1]), sample_layout(), period_s=1e-3)


def test_program_span_and_cut() -> None:
    rows = _rows(list(range(10)))
    line = len(ROW_HEADER) + sample_layout().index("program_line")
    rows[:3, line] = 0
    rows[8:, line] = 0  # the line drops one period before the motion's last step (row 8)
    x = len(ROW_HEADER) + sample_layout().index("x.pos_cmd")
    rows[9:, x] = rows[8, x]
    trace = rows_to_trace(rows, sample_layout(), period_s=1e-3)
    assert trace.program_span() == slice(3, 9)
    assert trace.program_time_s == pytest.approx(6e-3)
    cut = trace.cut(trace.program_span())
    assert cut.tick.tolist() == [0, 1, 2, 3, 4, 5]
    assert cut.pos_cmd_m[0, 0] == pytest.approx(0.403)


def test_the_bridge_stamps_pairs_and_counts() -> None:
    from feed_twin.linuxcnc.bridge import ServoBridge

    layout = sample_layout()
    line = len(ROW_HEADER) + layout.index("program_line")
    fb = len(ROW_HEADER) + layout.index("x.pos_fb")
    rows = _rows(list(range(100, 110)))
    rows[:3, line] = 0  # the program's first motion is tick 103
    rows[:, fb] = 400.0 + np.arange(10)  # mm
    bridge = ServoBridge(layout, period_s=1e-3, joint=0)
    assert bridge.take(rows[:2], now_s=0.0) is None  # nothing to publish before the program
    first = bridge.take(rows[2:6], now_s=0.0)
    assert first is not None, "rows of the program's motion are published"
    assert first.tick.tolist() == [103, 104, 105]
    assert first.stamp_ns.tolist() == [0, 1_000_000, 2_000_000]
    assert first.line.tolist() == [7, 7, 7]
    # row k's feedback is period k - 1's: tick 104's row answers stamp 0
    assert first.measured_stamp_ns.tolist() == [0, 1_000_000]
    assert first.measured_pos_m == pytest.approx([0.404, 0.405])
    # a gap of two ticks (107, 108 missing) is counted, the stamps keep the tick count
    second = bridge.take(rows[[6, 9]], now_s=100.15)
    assert second is not None, "rows of the program's motion are published"
    assert second.stamp_ns.tolist() == [3_000_000, 6_000_000]
    assert (bridge.received, bridge.lost, bridge.published) == (8, 2, 5)
    bridge.twin_output(3_000_000, now_s=100.0 + 106e-3 + 5e-3)
    bridge.mark_published(second, 0, 2, now_s=100.2)
    report = bridge.report()
    assert report["twin_output_latency_p50_ms"] == pytest.approx(5.0)
    assert report["bridge_latency_max_ms"] == pytest.approx((100.2 - 100.106) * 1e3)
    # its parts: the reader took each row 0.2 ms after its tick (_rows), the bridge took the
    # batch at 100.15 s (tick 106's row waited 43.8 ms for it) and published it 50 ms later
    parts = report["bridge_latency_parts_p99_ms"]
    assert isinstance(parts, dict)
    assert parts["servo_to_reader"] == pytest.approx(0.2)
    assert parts["reader_to_bridge"] == pytest.approx(43.8, abs=0.1)
    assert parts["bridge_to_published"] == pytest.approx(50.0)
    # the servo thread's own timing over every received period (the rows are on time)
    assert report["servo_periods"] == 8
    assert report["servo_late_periods"] == 0
    assert report["servo_lateness_max_ms"] == pytest.approx(0.0, abs=1e-6)
    histogram = report["servo_histogram"]
    assert isinstance(histogram, list) and sum(histogram) == 8
    from feed_twin.linuxcnc.summary import servo_timing_from_report

    timing = servo_timing_from_report(report)
    assert timing is not None and timing.periods == 8
    assert servo_timing_from_report({"samples_received": 8}) is None
