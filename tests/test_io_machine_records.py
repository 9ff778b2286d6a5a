"""Records as machines write them: signs, offsets, current constants, RMS readings, time units,
segments, and the bad inputs that must end in one clear line."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.cli import main
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import MeasuredDataError, load_column_map, load_measured, segment

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"

MAP = """\
time: {column: time, unit: ms}
position_sensor: motor_encoder
signals:
  pos_cmd_m: {column: x_cmd, unit: mm}
  pos_meas_m: {column: x_act, unit: mm}
  force_cmd_N: {column: i_q, unit: A, gain: -40.0, offset: 0.25, amplitude: rms}
plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _record(n: int = 1000, h_ms: float = 1.0) -> dict[str, np.ndarray]:
    t_ms = h_ms * np.arange(n)
    x_mm = 50.0 * (1.0 - np.cos(2.0 * math.pi * t_ms / (n * h_ms)))
    return {"time": t_ms, "x_cmd": x_mm, "x_act": x_mm - 0.01, "i_q": np.sin(t_ms / 100.0)}


def _csv(tmp_path: Path, cols: dict[str, np.ndarray], name: str = "run.csv") -> Path:
    names = list(cols)
    rows = np.column_stack([cols[k] for k in names])
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in rows]
    return _write(tmp_path, name, "\n".join(lines) + "\n")


def test_sign_offset_rms_and_force_constant_of_a_current_column(tmp_path):
    cols = _record()
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))
    # force = K_F * sqrt(2) * (reading - offset), with K_F negative: the drive counts the
    # current against the motion
    expected = -40.0 * math.sqrt(2.0) * (cols["i_q"] - 0.25)
    np.testing.assert_allclose(run["force_cmd_N"], expected, rtol=1e-12)


def test_a_current_needs_the_force_constant_to_become_a_force(tmp_path):
    path = _write(tmp_path, "m.yaml", MAP.replace(", gain: -40.0", ""))
    with pytest.raises(ConfigError, match=r"force_cmd_N.gain = None: a current gives force_cmd_N"):
        load_column_map(path)


def test_rms_is_only_for_currents(tmp_path):
    text = MAP.replace("{column: x_act, unit: mm}", "{column: x_act, unit: mm, amplitude: rms}")
    with pytest.raises(ConfigError, match=r"amplitude = 'rms' with unit = 'mm': only a current"):
        load_column_map(_write(tmp_path, "m.yaml", text))


def test_time_gain_is_honoured(tmp_path):
    """A time column in sample counts: unit s with the sample period as its gain."""
    cols = _record()
    cols["time"] = np.arange(len(cols["time"]), dtype=float) + 7.0
    text = MAP.replace("{column: time, unit: ms}", "{column: time, unit: s, gain: 0.001}")
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", text))
    assert run.sample_period_s == pytest.approx(1e-3, rel=1e-12)
    assert run.t_s[0] == pytest.approx(7e-3, rel=1e-12)


def test_time_gain_must_be_positive(tmp_path):
    text = MAP.replace("{column: time, unit: ms}", "{column: time, unit: s, gain: -1.0}")
    with pytest.raises(ConfigError, match=r"time.gain = -1.0: must be > 0"):
        load_column_map(_write(tmp_path, "m.yaml", text))


def test_milliseconds_declared_as_seconds_are_caught_at_once(tmp_path):
    text = MAP.replace("{column: time, unit: ms}", "{column: time, unit: s}")
    with pytest.raises(MeasuredDataError, match=r"period of 1 s.*ms declared as s"):
        load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", text))


def test_a_long_gap_is_refused_instead_of_filled(tmp_path):
    cols = _record()
    cols["time"][500:] += 60_000.0  # one minute without samples in a 1 kHz record
    with pytest.raises(MeasuredDataError, match=r"a gap of 60 s .*\(--segment t0:t1\)"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_a_short_gap_is_still_filled(tmp_path):
    cols = _record()
    cols = {k: np.delete(v, range(400, 405)) for k, v in cols.items()}
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))
    assert len(run.t_s) == 1000
    assert any("1 gap(s)" in w for w in run.warnings)


@pytest.mark.parametrize("column", ["x_act", "i_q"])
def test_a_constant_channel_is_refused(tmp_path, column):
    cols = _record()
    cols[column] = np.full_like(cols[column], 3.0)
    with pytest.raises(MeasuredDataError, match=rf"column '{column}' .* holds one value"):
        load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", MAP))


def test_a_binary_file_is_refused(tmp_path):
    path = tmp_path / "run.csv"
    path.write_bytes(b"time,x_cmd\n\x00\x01\x02\x03")
    with pytest.raises(MeasuredDataError, match=r"is not a text CSV \(binary data at byte 11\)"):
        load_measured(path, _write(tmp_path, "m.yaml", MAP))


def test_a_ragged_file_names_the_line(tmp_path):
    path = _csv(tmp_path, _record())
    lines = path.read_text().splitlines()
    lines[7] = lines[7].rsplit(",", 1)[0]  # a row cut short
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(MeasuredDataError, match=r"line 8 has 3 cells but the header has 4"):
        load_measured(path, _write(tmp_path, "m.yaml", MAP))


def test_segment_keeps_the_chosen_time_window(tmp_path):
    run = load_measured(_csv(tmp_path, _record()), _write(tmp_path, "m.yaml", MAP))
    part = segment(run, 0.2, 0.7)
    assert part.t_s[0] == pytest.approx(0.2) and part.t_s[-1] == pytest.approx(0.7)
    np.testing.assert_array_equal(part["pos_meas_m"], run["pos_meas_m"][200:701])
    with pytest.raises(MeasuredDataError, match=r"segment 0.2:0.3 holds 101 samples"):
        segment(run, 0.2, 0.3)


def _nominal_gain() -> float:
    from feed_twin.analysis.twin import ModelDoc

    gain = ModelDoc.load(NOMINAL).reference_gain
    assert gain is not None, f"{NOMINAL.name} records its effort's reference gain"
    return gain


def _emps_record(tmp_path: Path, *, gain: float) -> tuple[Path, Path]:
    from feed_twin.analysis.synthetic import generate, write_csv
    from feed_twin.analysis.twin import ModelDoc

    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, {"coulomb_friction": {"F_c_N": 15.0}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    text = map_path.read_text()
    map_path.write_text(text.replace(f"gain: {nominal.reference_gain!r}", f"gain: {gain!r}"))
    return tmp_path / "run.csv", map_path


@pytest.mark.slow
def test_a_reversed_effort_sign_is_said_in_one_line(tmp_path, capsys):
    gain = _nominal_gain()
    csv, map_path = _emps_record(tmp_path, gain=-gain)
    code = main(["diagnose", str(csv), "--config", str(NOMINAL), "--map", str(map_path),
                 "--out", str(tmp_path / "out")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1
    assert "force_cmd_N fits the nominal twin's better with its sign reversed" in err
    assert "give its column a negative gain in the map" in err


def test_out_naming_an_existing_file_is_refused(tmp_path, capsys):
    taken = _write(tmp_path, "report", "not a directory")
    code = main(["diagnose", "x.csv", "--config", str(NOMINAL), "--out", str(taken)])
    assert code == 2
    assert f"--out {taken}: is an existing file; name a directory" in capsys.readouterr().err
    code = main(["simulate", "--config", str(NOMINAL), "--measured", "x.csv",
                 "--out", str(tmp_path)])  # fmt: skip
    assert code == 2
    assert "is a directory; name the CSV file to write" in capsys.readouterr().err


@pytest.mark.slow
def test_simulate_from_the_program_on_a_segment(tmp_path, capsys):
    """A scope without command: simulate plans the G-code that ran and places it on the clock."""
    from feed_twin.analysis.synthetic import NC_CONFIG, PROGRAM

    gain = _nominal_gain()
    csv, map_path = _emps_record(tmp_path, gain=gain)
    map_path.write_text(
        map_path.read_text().replace("  pos_cmd_m: {column: x_cmd_mm, unit: mm}\n", "")
    )
    model = yaml.safe_load(NOMINAL.read_text()) | yaml.safe_load(NC_CONFIG)
    model_path = _write(tmp_path, "model.yaml", yaml.safe_dump(model))
    program = _write(tmp_path, "part.ngc", PROGRAM)
    out = tmp_path / "traces.csv"
    code = main(["simulate", "--config", str(model_path), "--measured", str(csv),
                 "--map", str(map_path), "--program", str(program), "--segment", "0:6",
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    data = np.genfromtxt(out, delimiter=",", names=True)
    assert data["t_s"][-1] == pytest.approx(6.0)
    # the command came from the program: the twin (without the record's 15 N of Coulomb
    # friction, 15 N / (kp kv gtau) = 11 um of following error) follows the table within tens of
    # micrometres, where one sample of misplacement at 0.12 m/s would be 120 um
    assert np.max(np.abs(data["sim_pos_meas_m"] - data["pos_meas_m"])) < 4e-5


@pytest.mark.slow
def test_report_json_keeps_the_efforts_unit(tmp_path):
    gain = _nominal_gain()
    csv, map_path = _emps_record(tmp_path, gain=gain)
    code = main(["diagnose", str(csv), "--config", str(NOMINAL), "--map", str(map_path),
                 "--out", str(tmp_path / "out")])  # fmt: skip
    assert code == 0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["before"]["effort_unit"] == "N"
    assert report["after"]["effort_rms"] < report["before"]["effort_rms"]
    assert "effort_rms_N" not in report["before"]


def test_trace_filter_is_read_from_the_map_and_kept_by_a_segment(tmp_path):
    cols = _record()
    text = MAP.replace("position_sensor: motor_encoder", "position_sensor: motor_encoder\n"
                       "trace_filter: mean")  # fmt: skip
    run = load_measured(_csv(tmp_path, cols), _write(tmp_path, "m.yaml", text))
    assert run.trace_filter == "mean"
    assert segment(run, 0.1, 0.9).trace_filter == "mean"
    bad = text.replace("trace_filter: mean", "trace_filter: median")
    with pytest.raises(ConfigError, match=r"trace_filter"):
        load_column_map(_write(tmp_path, "bad.yaml", bad))


def test_window_mean_is_the_mean_over_the_period_ending_at_each_sample():
    from feed_twin.analysis.recorder import window_mean

    ticks = np.arange(60, dtype=float)[None, :] ** 2
    out = window_mean(ticks, 20)
    assert out.shape == (1, 3)
    assert out[0, 0] == 0.0  # the first sample: itself
    assert out[0, 1] == pytest.approx(np.mean(np.arange(1, 21) ** 2))
    assert out[0, 2] == pytest.approx(np.mean(np.arange(21, 41) ** 2))


@pytest.mark.slow
def test_report_json_keeps_an_effort_in_amperes_in_amperes(tmp_path):
    """A drive that records its q-current: report.json says A, and its RMS is the amperes that
    `simulate` shows (the issue: `effort_rms_N` held amperes)."""
    from feed_twin.analysis.synthetic import NC_CONFIG, generate, write_csv
    from feed_twin.analysis.twin import ModelDoc

    axis = ROOT / "config" / "axis_default.yaml"
    nominal = ModelDoc.load(axis)
    program = (ROOT / "tests" / "fixtures" / "analysis" / "long_travel.ngc").read_text()
    nc = NC_CONFIG.replace("a_max_m_s2: 0.8", "a_max_m_s2: 3.0")
    csv = tmp_path / "run.csv"
    map_path = write_csv(csv, generate(nominal, {}, program=program, nc_config=nc), nominal)
    assert "current_q_A: {column: i_q_A, unit: A}" in map_path.read_text()
    out = tmp_path / "out"
    code = main(["diagnose", str(csv), "--config", str(axis), "--map", str(map_path),
                 "--out", str(out)])  # fmt: skip
    assert code == 0
    before = json.loads((out / "report.json").read_text())["before"]
    assert before["effort_unit"] == "A" and "effort_rms_N" not in before
    traces = tmp_path / "traces.csv"
    code = main(["simulate", "--config", str(axis), "--measured", str(csv), "--map",
                 str(map_path), "--out", str(traces)])  # fmt: skip
    assert code == 0
    data = np.genfromtxt(traces, delimiter=",", names=True)
    rms = math.sqrt(float(np.mean((data["current_q_A"] - data["sim_current_q_A"]) ** 2)))
    assert before["effort_rms"] == pytest.approx(rms, rel=1e-6)
