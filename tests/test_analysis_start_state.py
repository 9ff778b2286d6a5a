"""A record that begins mid-motion: the twin starts from the measured state, not from rest."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.recorder import start_velocity
from feed_twin.analysis.synthetic import Unmodelled, generate, write_csv
from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import load_measured

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"


def test_start_velocity_of_a_quantised_ramp():
    t = 1e-3 * np.arange(50)
    x = np.round((0.01 + 0.08 * t + 0.5 * 2.0 * t**2) / 5e-8) * 5e-8  # encoder counts
    # the slope at t_0 of a quadratic over 7 samples: quantisation of 5e-8 m over 6 ms
    assert start_velocity(t, x) == pytest.approx(0.08, abs=2e-5)


def test_twin_started_from_the_measured_state_follows_from_the_first_sample(tmp_path):
    """The EMPS twin on its own (exact) record, cut to start at full speed: from the measured
    state the following error agrees from the first sample; from rest it is off by tens of
    micrometres while the loop catches up."""
    nominal = ModelDoc.load(EMPS)
    exact = Unmodelled(effort_noise_std=0.0, current_lag_s=0.0, coupling_stiffness_factor=1.0)
    columns = generate(nominal, {}, unmodelled=exact)
    v = np.gradient(columns["x_cmd_mm"], columns["time_ms"])  # [m/s]
    start = int(np.argmax(np.abs(v) > 0.09))  # mid-move, at more than 90 mm/s
    cut = {k: c[start:] for k, c in columns.items()}
    map_path = write_csv(tmp_path / "run.csv", cut, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    twin = Twin.compile(nominal)
    drive = drive_from_run(run)
    assert abs(drive.v0_m_s) > 0.08  # the table lags its command a little
    early = slice(0, 20)
    x = run["pos_meas_m"]
    measured_start = twin.simulate(drive, twin.nominal[None, :]).x_m[0]
    from_rest = twin.simulate(dataclasses.replace(drive, v0_m_s=0.0), twin.nominal[None, :])
    dev = np.abs(measured_start - x)[early].max()
    dev_rest = np.abs(from_rest.x_m[0] - x)[early].max()
    # 0.49 um: the start state carries position and velocity, not the acceleration of the
    # moment (the drive's force is the loop's, recomputed from them on the first tick)
    assert dev < 1e-6
    assert dev_rest > 500 * dev  # 1.1 mm


def test_a_50_hz_averaged_trace_is_matched_by_averaging_the_twin_and_interpolating_the_command(
    tmp_path,
):
    """A drive's trace: each channel averaged over 20 ms, sampled at 50 Hz. The twin driven by
    the interpolated 50 Hz command and averaged the same way (map: trace_filter: mean) follows
    the trace; point samples of the twin would be off by the average's smoothing."""
    nominal = ModelDoc.load(EMPS)
    exact = Unmodelled(effort_noise_std=0.0, current_lag_s=0.0, coupling_stiffness_factor=1.0)
    fine = generate(nominal, {}, unmodelled=exact)
    n = len(fine["time_ms"]) // 20 * 20

    def trace(c):
        return c[:n].reshape(-1, 20).mean(axis=1)

    cols = {k: trace(v) for k, v in fine.items()}
    cols["time_ms"] = fine["time_ms"][19:n:20]  # stamped at the end of each window
    map_path = write_csv(tmp_path / "run.csv", cols, nominal)
    text = map_path.read_text().replace("position_sensor:", "trace_filter: mean\nposition_sensor:")
    map_path.write_text(text)
    run = load_measured(tmp_path / "run.csv", map_path)
    twin = Twin.compile(nominal)
    drive = drive_from_run(run)
    assert drive.trace_mean
    f = run["force_cmd_N"]
    averaged = twin.simulate(drive, twin.nominal[None, :]).effort
    pointwise = twin.simulate(
        dataclasses.replace(drive, trace_mean=False), twin.nominal[None, :]
    ).effort
    assert averaged is not None and pointwise is not None, "the map names force_cmd_N"
    averaged, pointwise = averaged[0], pointwise[0]
    # past the first 0.2 s: the first samples average time before the record began
    late = run.t_s - run.t_s[0] > 0.2
    err = np.sqrt(np.mean((averaged - f)[late] ** 2))
    err_point = np.sqrt(np.mean((pointwise - f)[late] ** 2))
    # 4.0 N against 16.0 N: what is left comes from the command rebuilt from its 50 Hz means
    # (the loop turns a micrometre of command into 1.4 N)
    assert err < 0.3 * err_point


def test_a_new_drive_is_simulated_on_its_own_command_after_the_last_one_was_collected(tmp_path):
    """The twin caches a drive's inputs: a drive made right after the previous one was
    collected (as the program alignment's refinement loop does) can get its memory, and so its
    id(), and must still be simulated on its own command."""
    nominal = ModelDoc.load(EMPS)
    columns = generate(nominal, {})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    twin = Twin.compile(nominal)
    shift_m = 2e-3
    shifted = drive_from_run(run.with_signals(pos_cmd_m=run["pos_cmd_m"] + shift_m))
    first = drive_from_run(run)
    twin.simulate(first, twin.nominal[None, :])
    del first
    second = copy.copy(shifted)  # CPython hands it the block `first` had
    got = twin.simulate(second, twin.nominal[None, :]).x_m[0]
    # the table follows the shifted command: its end position moves with it
    assert got[-1] - run["pos_meas_m"][-1] == pytest.approx(shift_m, abs=1e-4)
