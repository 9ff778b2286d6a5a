"""Monitoring logs at 1-100 Hz: time from the row rate, float-rounded periods, rows out of
order, repeated or missing named by file line, and plausibility on the segment used."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.cli import split_validate
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import MeasuredDataError, load_column_map, load_measured

MAP = """\
{time}
position_sensor: linear_scale
signals:
  pos_cmd_m: {{column: x_set, unit: mm}}
  pos_meas_m: {{column: x_act, unit: mm}}
plausibility: {{travel_m: 0.5, max_speed_m_s: 0.1}}
"""
INDEX = "time: {index: true, rate_hz: 10}"


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _log(n: int = 400, rate_hz: float = 10.0) -> dict[str, np.ndarray]:
    """A 10 Hz log of a slow back-and-forth move, rounded to 0.1 mm as a display prints it."""
    t = np.arange(n) / rate_hz
    x = 100.0 + 40.0 * np.sin(2.0 * math.pi * t / 40.0)
    return {"t": t, "x_set": np.round(x, 1), "x_act": np.round(x - 0.05, 1)}


def _csv(tmp_path: Path, cols: dict[str, np.ndarray], *, time: bool = True) -> Path:
    names = [k for k in cols if time or k != "t"]
    rows = np.column_stack([cols[k] for k in names])
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in rows]
    return _write(tmp_path, "log.csv", "\n".join(lines) + "\n")


def test_time_from_the_row_index_at_the_maps_rate(tmp_path):
    path = _csv(tmp_path, _log(), time=False)
    run = load_measured(path, _write(tmp_path, "m.yaml", MAP.format(time=INDEX)))
    assert run.sample_period_s == pytest.approx(0.1, rel=1e-12)
    assert run.t_s[-1] == pytest.approx(39.9, rel=1e-12)


def test_rate_on_the_command_line_replaces_a_missing_time(tmp_path):
    path = _csv(tmp_path, _log(rate_hz=20.0), time=False)
    cmap = _write(tmp_path, "m.yaml", MAP.format(time=""))
    run = load_measured(path, cmap, rate_hz=20.0)
    assert run.sample_period_s == pytest.approx(0.05, rel=1e-12)
    with pytest.raises(MeasuredDataError, match=r"gives no time; .* or --rate HZ"):
        load_measured(path, cmap)
    with pytest.raises(MeasuredDataError, match=r"--rate -5.0: must be a positive number"):
        load_measured(path, cmap, rate_hz=-5.0)


def test_row_time_needs_index_true(tmp_path):
    text = MAP.format(time="time: {index: false, rate_hz: 10}")
    with pytest.raises(ConfigError, match=r"index = False: time from the row index needs"):
        load_column_map(_write(tmp_path, "m.yaml", text))


@pytest.mark.parametrize("gain", [0.1, 0.0999999, 0.1000001])
def test_a_10_hz_period_with_float_rounding_is_accepted(tmp_path, gain):
    cols = _log()
    cols["t"] = np.arange(len(cols["t"]), dtype=float) * 1.0000000000000142
    time = f"time: {{column: t, unit: s, gain: {gain}}}"
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP.format(time=time)))
    assert run.sample_period_s == pytest.approx(0.1, rel=2e-6)
    assert np.ptp(np.diff(run.t_s)) < 1e-9  # one uniform grid


def test_a_repeated_stamp_is_named_by_line(tmp_path):
    cols = _log()
    cols["t"][120] = cols["t"][119]
    time = "time: {column: t, unit: s}"
    with pytest.raises(
        MeasuredDataError, match=r"log.csv:122: time column 't' repeats t = 11.9 s of line 121"
    ):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP.format(time=time)))


def test_missing_rows_are_filled_and_named(tmp_path):
    cols = {k: np.delete(v, range(200, 205)) for k, v in _log().items()}
    time = "time: {column: t, unit: s}"
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP.format(time=time)))
    (note,) = run.warnings
    assert "rows missing (the first after" in note and "log.csv:201" in note
    assert "5 sample(s) inserted" in note
    assert run.where(201) == f"{run.source} at t = 20.1 s"  # a filled sample has no line
    assert run.where(199) == f"{run.file}:201"


def test_rows_shuffled_in_blocks_are_named_by_line(tmp_path):
    cols = _log()
    order = np.concatenate([np.arange(200, 300), np.arange(0, 200), np.arange(300, 400)])
    shuffled = {k: v[order] for k, v in cols.items()}
    cmap = _write(tmp_path, "m.yaml", MAP.format(time=INDEX))
    with pytest.raises(MeasuredDataError) as info:
        load_measured(_csv(tmp_path, shuffled, time=False), cmap)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{tmp_path / 'log.csv'}:102: column 'x_set' (pos_cmd_m) jumps")
    assert "(2 such row(s)): rows out of order or missing; sort the file" in message


def test_plausibility_looks_at_the_segment_used(tmp_path):
    cols = _log()
    cols["x_set"][350:] += 300.0  # a jump far outside the part that is used
    cmap = _write(tmp_path, "m.yaml", MAP.format(time=INDEX))
    path = _csv(tmp_path, cols, time=False)
    with pytest.raises(
        MeasuredDataError,
        match=r"log.csv:352: column 'x_set' \(pos_cmd_m, declared in mm\) jumps 0.3004 m",
    ):
        load_measured(path, cmap)
    run = load_measured(path, cmap, window=(0.0, 30.0))
    assert run.t_s[-1] == pytest.approx(30.0)


def test_validate_takes_a_segment():
    assert split_validate("run.csv:10:20.5") == ("run.csv", "10:20.5")
    assert split_validate("run.csv") == ("run.csv", None)
    assert split_validate("dir/a:b.csv") == ("dir/a:b.csv", None)


def test_a_period_slower_than_a_second_is_refused_naming_it(tmp_path):
    cols = _log()
    cols["t"] = cols["t"] * 20.0  # 2 s between rows: ms declared as s?
    time = "time: {column: t, unit: s}"
    with pytest.raises(MeasuredDataError) as info:
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP.format(time=time)))
    message = str(info.value)
    assert "gives a sample period of 2 s, slower than any record the twin can compare" in message
    assert "\n" not in message


def test_a_bag_cannot_take_its_time_from_a_row_rate(tmp_path):
    cmap = _write(tmp_path, "m.yaml", MAP.format(time=INDEX))
    with pytest.raises(MeasuredDataError, match=r"a bag's time is a topic field, not a row rate"):
        load_measured(tmp_path, cmap)
