"""The first samples of a 50 Hz averaged trace are not evidence about effects: the first averages
time before the twin's start, and the twin settles from a start state read off averaged samples
for a few of its loop's time constants (Twin.first_evidence)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.channels import noise_floors, residuals, weighted_channels
from feed_twin.analysis.fit import cost_of
from feed_twin.analysis.synthetic import Unmodelled, generate, write_csv
from feed_twin.analysis.twin import Drive, ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import load_measured, segment

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"
TICKS = 20  # a 50 Hz trace of the 1 kHz loop


def _trace_run(tmp_path):
    """The exact EMPS twin's own record, averaged over 20 ms and sampled at 50 Hz, cut to begin
    at full speed."""
    nominal = ModelDoc.load(EMPS)
    exact = Unmodelled(effort_noise_std=0.0, current_lag_s=0.0, coupling_stiffness_factor=1.0)
    fine = generate(nominal, {}, unmodelled=exact)
    n = len(fine["time_ms"]) // TICKS * TICKS
    cols = {k: v[:n].reshape(-1, TICKS).mean(axis=1) for k, v in fine.items()}
    cols["time_ms"] = fine["time_ms"][TICKS - 1 : n : TICKS]  # stamped at the window's end
    map_path = write_csv(tmp_path / "run.csv", cols, nominal)
    text = map_path.read_text()
    map_path.write_text(text.replace("position_sensor:", "trace_filter: mean\nposition_sensor:"))
    run = load_measured(tmp_path / "run.csv", map_path)
    v = np.gradient(run["pos_meas_m"], run.t_s)
    half = len(v) // 2  # the fastest point of the record's first half: enough samples after it
    t_fast = float(run.t_s[int(np.argmax(np.abs(v[:half])))])
    return nominal, segment(run, t_fast, float(run.t_s[-1]))


def test_the_samples_left_out_follow_from_the_loops_settling_and_the_window():
    """EMPS: mass M, viscous friction F_v, drive gain g, velocity gain K_p, position gain K_v:
    the linear loop M s^2 + (F_v + K_p g) s + K_p g K_v = 0 has a lightly damped pair with
    decay rate sigma = (F_v + K_p g) / 2M = 46 1/s; its envelope is down to e^-3 after
    3/sigma = 65 ms, which the simulated settling matches (the last crossing of the 5 % band
    comes before the envelope's, the loop's sample delays make it slower). A 50 Hz sample
    averages the 20 ms ending at its stamp: the first evidence is the first whose window
    starts after the settling."""
    nominal = ModelDoc.load(EMPS)
    twin = Twin.compile(nominal)
    M, F_v, g, K_p = 95.1089, 203.5034, 35.15065188248547, 243.45
    sigma = (F_v + K_p * g) / (2.0 * M)
    settle = twin.settle_time_s()
    assert settle == pytest.approx(3.0 / sigma, rel=0.15)
    t = 0.02 * np.arange(50)
    first = twin.first_evidence(_drive(t, trace_mean=True))
    assert first == math.ceil((settle / 1e-3 + TICKS - 1) / TICKS) == 4
    raw = _drive(1e-3 * np.arange(50), trace_mean=True)  # 1 kHz: no window, the state itself
    assert twin.first_evidence(raw) == 0
    assert twin.first_evidence(_drive(t, trace_mean=False)) == 0


def _drive(t, *, trace_mean):
    return Drive.at_rest(t, trace_mean=trace_mean)


def test_the_start_transient_of_an_averaged_trace_is_left_out_of_the_fit(tmp_path):
    """The exact twin on its own averaged trace begun at full speed: its command and its
    start rebuilt from the 50 Hz means (recorder.deaveraged, Twin._started), the samples
    before first_evidence carry no start transient any more (320 N when the twin started at
    the first mean, half a window behind); those after follow to what the rebuilt command
    leaves (1.8 N RMS, 4.6 N from the means interpolated); the fit's cost does not see the
    first ones at all."""
    nominal, run = _trace_run(tmp_path)
    twin = Twin.compile(nominal)
    drive = drive_from_run(run)
    out = twin.simulate(drive, twin.nominal[None, :])
    start = twin.first_evidence(drive)
    assert start == 4
    assert out.effort is not None
    r = run["force_cmd_N"] - out.effort[0]
    early, late = r[:start], r[start:]
    assert np.max(np.abs(early)) < 10.0
    assert np.sqrt(np.mean(late**2)) < 2.5
    re, _ = residuals(run, out, start=start)
    assert re is not None
    assert np.all(re[:start] == 0.0) and np.array_equal(re[start:], late)
    floors = noise_floors(run, out, start=start)
    meas = weighted_channels(run, out, 1, floors, start=start)
    assert meas.scale_effort == pytest.approx(max(np.sqrt(np.mean(late**2)), floors["effort"]))
    # what the first samples measured does not change the cost
    assert meas.effort is not None
    spoilt = meas.effort.copy()
    spoilt[:start] += 1e3
    moved = weighted_channels(run, out, 1, floors, start=start)
    object.__setattr__(moved, "effort", spoilt)
    assert cost_of(moved, out) == cost_of(meas, out)
