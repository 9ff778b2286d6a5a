"""Measured-data import: column maps, unit conversion at the edge, repairs and bad input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.core.config import ConfigError
from feed_twin.io.measured import (
    MeasuredDataError,
    load_column_map,
    load_measured,
)

EMPS = Path("/work/shared/data/emps")
ROOT = Path(__file__).resolve().parents[1]

MAP = """\
time: {column: time, unit: ms}
position_sensor: linear_scale
signals:
  pos_cmd_m: {column: x_cmd, unit: mm}
  pos_meas_m: {column: x_act, unit: mm}
  vel_cmd_m_s: {column: feed, unit: mm/min}
  force_cmd_N: {column: u, unit: V, gain: 20.0}
conversion: {lead_m: 0.01, counts_per_rev: 4096}
plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _record(n: int = 1000, h_ms: float = 1.0) -> dict[str, np.ndarray]:
    t_ms = h_ms * np.arange(n)
    x_mm = 50.0 * (1.0 - np.cos(2.0 * math.pi * t_ms / (n * h_ms)))
    return {
        "time": t_ms,
        "x_cmd": x_mm,
        "x_act": x_mm - 0.01,
        "feed": np.gradient(x_mm, t_ms) * 60_000.0,
        "u": np.sin(t_ms / 100.0),
    }


def _csv(tmp_path: Path, cols: dict[str, np.ndarray], name: str = "run.csv") -> Path:
    names = list(cols)
    rows = np.column_stack([cols[k] for k in names])
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in rows]
    text = "\n".join(lines).replace("nan", "")
    return _write(tmp_path, name, text + "\n")


def test_units_converted_once_at_the_edge(tmp_path):
    cols = _record()
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))
    assert run.position_sensor == "linear_scale"
    np.testing.assert_allclose(run.t_s, cols["time"] * 1e-3, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run["pos_cmd_m"], cols["x_cmd"] * 1e-3, rtol=1e-12)
    np.testing.assert_allclose(run["vel_cmd_m_s"], cols["feed"] / 60_000.0, rtol=1e-12)
    np.testing.assert_allclose(run["force_cmd_N"], 20.0 * cols["u"], rtol=1e-12)
    assert run.sample_period_s == pytest.approx(1e-3, rel=1e-12)
    assert run.effort_name == "force_cmd_N"
    assert run.warnings == ()


def test_encoder_counts_and_degrees_become_table_travel(tmp_path):
    cols = _record()
    lead, cpr = 0.01, 4096
    cols["enc"] = np.round(cols["x_act"] * 1e-3 / lead * cpr)
    cols["deg"] = cols["x_act"] * 1e-3 / lead * 360.0
    text = MAP.replace("{column: x_act, unit: mm}", "{column: enc, unit: counts}").replace(
        "  vel_cmd_m_s", "  disturbance_motor_deg_N: {column: u, unit: N}\n  vel_cmd_m_s"
    )
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", text))
    # quantisation: one count is lead/cpr
    np.testing.assert_allclose(run["pos_meas_m"], cols["x_act"] * 1e-3, atol=lead / cpr)
    text2 = MAP.replace("{column: x_act, unit: mm}", "{column: deg, unit: deg}")
    run2 = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m2.yaml", text2))
    np.testing.assert_allclose(run2["pos_meas_m"], cols["x_act"] * 1e-3, rtol=1e-12)


def test_emps_map_reads_both_benchmark_files():
    cmap = load_column_map(ROOT / "config/emps_map.yaml")
    ident = load_measured(EMPS / "DATA_EMPS.csv", cmap)
    valid = load_measured(EMPS / "DATA_EMPS_PULSES.csv", cmap)
    assert len(ident.t_s) == 24841 and ident.sample_period_s == pytest.approx(1e-3, rel=1e-4)
    assert "disturbance_effort_add_N" not in ident
    # pulses are 0 or 5 V, times gtau
    assert set(np.unique(valid["disturbance_effort_add_N"])) == {0.0, 5.0 * 35.15065188248547}
    raw = np.genfromtxt(EMPS / "DATA_EMPS.csv", delimiter=",", skip_header=1)
    np.testing.assert_allclose(ident["force_cmd_N"], raw[:, 4], rtol=1e-9)


def test_nan_cells_are_interpolated_with_a_warning(tmp_path):
    cols = _record()
    cols["x_act"][[100, 101, 102, 500]] = np.nan
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))
    assert any("'x_act'" in w and "4 empty or NaN" in w for w in run.warnings)
    x = _record()["x_act"] * 1e-3
    # a linear bridge over a 4 ms hole misses by at most h^2/8 * max|x''| = 4e-6 m here
    x_dd = 50e-3 * (2.0 * math.pi) ** 2
    np.testing.assert_allclose(run["pos_meas_m"], x, atol=(4e-3) ** 2 / 8.0 * x_dd * 1.01)


def test_time_gaps_are_resampled_with_a_warning(tmp_path):
    cols = _record()
    keep = np.ones(1000, bool)
    keep[300:310] = False
    cols = {k: v[keep] for k, v in cols.items()}
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))
    assert len(run.t_s) == 1000
    assert any("1 gap(s)" in w and "10 sample(s) inserted" in w for w in run.warnings)
    np.testing.assert_allclose(np.diff(run.t_s), 1e-3, rtol=1e-9)


def test_missing_column_is_named(tmp_path):
    cols = _record()
    del cols["x_act"]
    with pytest.raises(MeasuredDataError, match=r"names column\(s\) 'x_act' \(for pos_meas_m\)"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_optional_column_may_be_missing(tmp_path):
    text = MAP.replace("{column: u, unit: V, gain: 20.0}", "{column: zz, unit: N, optional: true}")
    run = load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", text))
    assert "force_cmd_N" not in run


def test_mm_declared_as_m_is_caught(tmp_path):
    text = MAP.replace("{column: x_act, unit: mm}", "{column: x_act, unit: m}")
    with pytest.raises(
        MeasuredDataError, match=r"'x_act' \(pos_meas_m, declared in m\) spans 100 m"
    ):
        load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", text))


def test_mm_min_declared_as_m_s_is_caught(tmp_path):
    text = MAP.replace("unit: mm/min", "unit: m/s")
    with pytest.raises(MeasuredDataError, match=r"'feed' \(vel_cmd_m_s, declared in m/s\) reaches"):
        load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", text))


def test_implausible_speed_is_caught(tmp_path):
    text = MAP.replace("max_speed_m_s: 1.0", "max_speed_m_s: 0.01")
    with pytest.raises(
        MeasuredDataError,
        match=r"csv:\d+: column 'x_cmd' \(pos_cmd_m, declared in mm\) jumps .* rows out of order",
    ):
        load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", text))


def test_non_monotonic_time_is_named(tmp_path):
    cols = _record()
    cols["time"][400] = cols["time"][398]
    with pytest.raises(
        MeasuredDataError, match=r"csv:402: time column 'time' goes back from .* rows out of order"
    ):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_too_short_record(tmp_path):
    with pytest.raises(MeasuredDataError, match=r"too short \(150 samples"):
        load_measured(_csv(tmp_path, _record(n=150)), _write(tmp_path, "m.yaml", MAP))


def test_command_that_never_moves(tmp_path):
    cols = _record()
    cols["x_cmd"] = np.full(1000, 12.0)
    with pytest.raises(MeasuredDataError, match=r"'x_cmd' \(pos_cmd_m\) never moves"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_mostly_empty_column_is_not_repaired(tmp_path):
    cols = _record()
    cols["u"][::2] = np.nan
    with pytest.raises(MeasuredDataError, match=r"'u' \(for force_cmd_N\) is 50 % empty"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_nan_time_is_an_error(tmp_path):
    cols = _record()
    cols["time"][7] = np.nan
    with pytest.raises(MeasuredDataError, match=r"run.csv:9: time column 'time' is empty"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_missing_file_and_empty_file(tmp_path):
    with pytest.raises(MeasuredDataError, match=r"no such measured file"):
        load_measured(tmp_path / "nope.csv", _write(tmp_path, "m.yaml", MAP))
    with pytest.raises(MeasuredDataError, match=r"the file is empty"):
        load_measured(_write(tmp_path, "e.csv", ""), _write(tmp_path, "m.yaml", MAP))


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("unit: mm/min", "unit: furlong", r"signals.vel_cmd_m_s.unit = 'furlong': must be one of"),
        ("gain: 20.0", "gain: 0", r"signals.force_cmd_N.gain = 0.0: must be a finite number oth"),
        (", gain: 20.0", "", r"signals.force_cmd_N.gain = None: a column in V needs the drive"),
        ("  pos_cmd_m:", "  pos_cmd_mm:", r"signals.pos_cmd_mm: 'pos_cmd_mm' is not a canonical"),
        ("{column: feed, unit: mm/min}", "{column: feed, unit: N}", r"a force unit cannot give"),
        ("lead_m: 0.01, ", "", None),
        ("unit: ms}", "unit: mm}", r"time.unit = 'mm': must be a time unit"),
        ("travel_m: 1.0", "travel_m: 0", r"plausibility.travel_m = 0.0: must be > 0"),
        ("position_sensor: linear_scale", "position_sensor: laser", r"position_sensor = 'laser'"),
    ],
)
def test_bad_maps_name_file_field_and_value(tmp_path, old, new, message):
    text = MAP.replace(old, new)
    assert text != MAP
    path = _write(tmp_path, "m.yaml", text)
    if message is None:  # removing the lead alone is fine until an angle needs it
        load_column_map(path)
        text = text.replace("{column: x_act, unit: mm}", "{column: x_act, unit: deg}")
        path = _write(tmp_path, "m.yaml", text)
        message = r"signals.pos_meas_m.unit = 'deg': converting a motor angle .*lead_m"
    with pytest.raises(ConfigError, match=message) as info:
        load_column_map(path)
    assert str(path) in str(info.value)
