"""The trace between machine and record is part of the model, and identified: a delay of the
recorded position, a trace's averaging window, and delays searched over a range the record
sets, with a word when the best lies at its edge (analysis.record_search)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis import record_search
from feed_twin.analysis.channels import noise_floors, weighted_channels
from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.model_doc import (
    COMMAND_DELAY_SLOT,
    EFFORT_DELAY_SLOT,
    POSITION_DELAY_SLOT,
    RIPPLE_SLOTS,
)
from feed_twin.analysis.recorder import window_mean
from feed_twin.analysis.synthetic import as_trace, generate, write_csv
from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import load_measured

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"


def _record(tmp_path: Path, hidden: dict, *, window_ticks: int = 1):
    """A synthetic 1 kHz record; with `window_ticks` every recorded channel (not the
    command) is the mean over that many ticks ending at its sample (a trace filter)."""
    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, hidden)
    traced = {
        k: v if k in ("time_ms", "x_cmd_mm") else window_mean(v, 1, window_ticks)[0]
        for k, v in columns.items()
    }
    map_path = write_csv(tmp_path / "run.csv", traced, nominal)
    return nominal, load_measured(tmp_path / "run.csv", map_path)


def test_a_delay_of_the_recorded_position_is_named(tmp_path):
    """The position stamped 2 ms after the command and the effort: named, not "no missing
    effect" beside a position residual 3.35e4 x its noise."""
    nominal, run = _record(tmp_path, {"position_delay": {"delay_s": 0.002}})
    d, _, _ = diagnose(run, nominal)
    assert [e.name for e in d.effects] == ["position_delay"]
    assert d.effects[0].parameters["delay_s"] == pytest.approx(0.002, abs=2.5e-4)
    assert d.after.fe_dev_rms_m < 0.02 * d.before.fe_dev_rms_m


def test_a_declared_20_ms_mean_makes_the_fit_better_not_worse(tmp_path):
    """A 50 Hz trace whose every channel (the command too) is the mean over its 20 ms, as
    controllers export them, with 15 N of Coulomb friction. Declared (`trace_filter: mean`),
    the command is rebuilt from its means (recorder.deaveraged) before the twin's outputs are
    averaged: interpolating the means smoothed the command twice, and the declared record fit
    worse than the same taken as point samples (Coulomb 13.4 N beside a false drive gain, 22 %
    effort error left; as point samples a false 137 kg mass, 13 %)."""
    nominal = ModelDoc.load(NOMINAL)
    columns = as_trace(generate(nominal, {"coulomb_friction": {"F_c_N": 15.0}}), 20)
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    map_path.write_text(map_path.read_text() + "trace_filter: mean\n")
    run = load_measured(tmp_path / "run.csv", map_path)
    d, _, _ = diagnose(run, nominal)
    assert [e.name for e in d.effects] == ["coulomb_friction"]
    assert d.effects[0].parameters["F_c_N"] == pytest.approx(15.0, rel=0.02)
    assert d.after.effort_rel_err_pct is not None and d.after.effort_rel_err_pct < 8.0
    assert d.after.fe_dev_rms_m < 2e-6


def test_an_undeclared_mean_is_identified_on_the_truth_machine(tmp_path):
    """The independent truth machine's 50 Hz trace, each channel the mean over its period,
    the map silent about it: trace_window, ranked on the effort (the twin's effort as the
    trace's other mode records it, Motion.effort_other_mode), names the 20 ms, and the effort
    error (51 %) is gone. Ranked on the position it was not named: the command is a mean too
    and the twin reads it off a smooth curve, so the window's lag is the command's (3 um left),
    and a Coulomb force of 116 N was named instead (nothing hidden)."""
    from feed_twin.truth import Trace, make_record

    nominal = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    trace = Trace(period_s=0.02, average=True, declare_average=False)
    rec = make_record(tmp_path / "run.csv", trace=trace, seed=1)
    run = load_measured(rec.csv, rec.map)
    assert run.trace_filter == "none"
    d, _, _ = diagnose(run, nominal)
    found = {e.name: e.parameters for e in d.effects}
    assert list(found) == ["trace_window"], found
    assert found["trace_window"]["window_s"] == pytest.approx(0.020)
    assert d.after.fe_dev_rms_m < 0.6 * d.before.fe_dev_rms_m  # 3.1 -> 1.4 um
    assert d.before.effort_rel_err_pct is not None and d.after.effort_rel_err_pct is not None
    assert d.before.effort_rel_err_pct > 45.0
    assert d.after.effort_rel_err_pct < 10.0


def test_a_delay_is_searched_over_the_record_and_an_edge_is_said(tmp_path, monkeypatch):
    """The effort stamped 5 ms late, searched from an edit's grid of +/- 1 ms: the range is
    the record's (3 samples), widened while the best lies at its edge; with no widening
    left the best is at the edge and the result says so."""
    nominal, run = _record(tmp_path, {"channel_delay": {"delay_s": 0.005}})
    twin = Twin.compile(nominal)
    drive = drive_from_run(run)
    out = twin.simulate(drive, twin.nominal[None, :])
    meas = weighted_channels(run, out, 1, noise_floors(run, out))
    edit = BY_NAME["channel_delay"].edit(nominal, None)  # type: ignore[arg-type]
    narrow = type(edit)(**{**edit.__dict__, "grid": (-1e-3, 0.0, 1e-3)})
    found = record_search.search(twin, narrow, drive, meas)
    assert found.values[EFFORT_DELAY_SLOT] == pytest.approx(0.005, abs=5e-4)
    assert not found.message.endswith(record_search.AT_EDGE)
    assert "over [-6, 6] ms" in found.message  # 3 ms, doubled once
    monkeypatch.setattr(record_search, "WIDENINGS", 0)
    edge = record_search.search(twin, narrow, drive, meas)
    assert edge.values[EFFORT_DELAY_SLOT] == pytest.approx(0.003, abs=1e-6)
    assert edge.message.endswith(
        f"over [-3, 3] ms; the best, 3 ms, lies {record_search.AT_EDGE}"
    ), edge.message
    assert found.cost < edge.cost


def test_averaging_as_declared_is_the_model_until_a_window_is_fitted():
    """Twin.record_slots: without a window of its own the twin averages as the map says."""
    nominal = ModelDoc.load(NOMINAL)
    twin = Twin.compile(nominal)
    t = 0.02 * np.arange(50)
    from feed_twin.analysis.twin import Drive

    slots = twin.record_slots(Drive.at_rest(t, trace_mean=True))
    assert slots[record_search.TRACE_WINDOW_SLOT] == pytest.approx(0.02)
    assert twin.record_slots(Drive.at_rest(t))[record_search.TRACE_WINDOW_SLOT] == 1e-3
    fitted = Twin.compile(nominal.set(record_search.TRACE_WINDOW_SLOT, 0.005))
    assert fitted.record_slots(Drive.at_rest(t, trace_mean=True))[
        record_search.TRACE_WINDOW_SLOT
    ] == pytest.approx(0.005)


def _with_pole_pairs(doc: ModelDoc, p: int = 3) -> ModelDoc:
    import dataclasses

    return dataclasses.replace(doc, data={**doc.data, "analysis": {"pole_pairs": p}})


def test_phase_current_offsets_without_a_current_sensor_are_not_cogging(tmp_path):
    """The EMPS twin drives its table with an effort source (no motor, no current sensor);
    the drive's phase-current offsets leave a ripple once per electrical revolution (3 per
    motor revolution) in the recorded effort. Named current_offset with its offsets, not
    cogging torque (whose orders leave out the pole pairs)."""
    nominal = _with_pole_pairs(ModelDoc.load(NOMINAL))
    gain = nominal.reference_gain
    assert gain is not None
    # offsets of +0.03, -0.01, -0.02 V on the drive's three phase sensors (the EMPS effort is
    # a voltage): alpha = 0.03, beta = (o_b - o_c) / sqrt(3)
    offsets = (0.03, -0.01, -0.02)
    alpha, beta = offsets[0], (offsets[1] - offsets[2]) / np.sqrt(3.0)
    truth = nominal.set(RIPPLE_SLOTS[0], -alpha * gain).set(RIPPLE_SLOTS[1], beta * gain)
    columns = generate(truth, {"coulomb_friction": {"F_c_N": 10.0}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    run = load_measured(tmp_path / "run.csv", map_path)
    d, _, _ = diagnose(run, nominal)
    found = {e.name: e.parameters for e in d.effects}
    assert "cogging_torque" not in found and "current_offset" in found, found
    for k, x in enumerate("abc"):
        assert found["current_offset"][f"offset_{x}_A"] == pytest.approx(offsets[k], abs=3e-3)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(10.0, rel=0.1)


def test_pole_pairs_of_an_effort_source_twin_must_be_whole():
    doc = _with_pole_pairs(ModelDoc.load(NOMINAL))
    bad = type(doc)(data={**doc.data, "analysis": {"pole_pairs": 2.5}}, source="m.yaml")
    with pytest.raises(ConfigError) as err:
        Twin.compile(bad)
    assert str(err.value) == "m.yaml: analysis.pole_pairs = 2.5: must be a whole number >= 1"


def test_the_records_rounding_floors_its_noise():
    """A position rounded to 1 um (a trace's display digits) that rests between two counts has
    no sample-to-sample noise; its rounding noise, q / sqrt(12), is the least its channel's
    noise can be (an effect is not named for the rounding)."""
    from feed_twin.analysis.channels import quantisation_step
    from feed_twin.analysis.fit import SimOutputs
    from feed_twin.io.measured import MeasuredRun

    q = 1e-6
    t = 1e-3 * np.arange(4000)
    x = 0.1 + 2e-6 * np.sin(2.0 * np.pi * t) + 1e-3 * np.clip(t - 3.0, 0.0, None)
    rounded = np.round(x / q) * q
    assert quantisation_step(rounded) == pytest.approx(q, rel=1e-6)
    assert quantisation_step(x) == 0.0  # not rounded: no step of its own
    assert quantisation_step(0.1 * t) == 0.0  # a ramp's equal gaps are no step
    run = MeasuredRun(
        source="trace.csv", t_s=t, signals={"pos_meas_m": rounded}, position_sensor="linear_scale"
    )
    out = SimOutputs(x_m=x[None, :], effort=None, ok=np.ones(1, dtype=bool))
    floors = noise_floors(run, out)
    assert floors["position"] == pytest.approx(q / np.sqrt(12.0), rel=1e-6)


def test_a_moving_channel_rounded_to_its_scale_floors_its_noise_at_its_rounding():
    """A 1 kHz trace of a table that travels 0.3 m and rests a little, printed in
    10 nm steps (mm to 5 decimals): 97 % of its values are distinct, and at constant speed the
    rounding repeats, so its sample-to-sample noise reads 6e-16 m. Its step is found (values on
    the grid, changes of many steps), read off the whole span (the smallest gap's float noise
    over 3e7 steps was a fifth of a step), and floors the channel's noise at q / sqrt(12): the
    truth machine's verdicts had said 9.3e5 x a sample noise of 1e-12 m."""
    from feed_twin.analysis.channels import quantisation_step
    from feed_twin.analysis.fit import SimOutputs
    from feed_twin.io.measured import MeasuredRun

    q = 1e-8
    t = 1e-3 * np.arange(10000)
    x = 0.2 + 0.15 * (1.0 - np.cos(np.pi * np.clip((t - 0.3) / 9.4, 0.0, 1.0)))  # rests 0.3 s
    rounded = np.round(x * 1e3, 5) * 1e-3  # as a CSV in mm prints it
    assert len(np.unique(rounded)) > 0.9 * len(t)
    assert quantisation_step(rounded) == pytest.approx(q, rel=1e-6)
    assert quantisation_step(x + 1e-9 * np.sin(7.0 * t)) == 0.0  # not rounded
    assert quantisation_step(0.2 + 0.1 * t) == 0.0  # a ramp's equal gaps are still no step
    run = MeasuredRun(
        source="trace.csv", t_s=t, signals={"pos_meas_m": rounded}, position_sensor="linear_scale"
    )
    out = SimOutputs(x_m=x[None, :], effort=None, ok=np.ones(1, dtype=bool))
    assert noise_floors(run, out)["position"] == pytest.approx(q / np.sqrt(12.0), rel=1e-6)


def test_a_command_followed_a_fraction_of_a_tick_late_is_found_to_its_step(tmp_path):
    """A drive that follows its command 0.3 ms later than the twin's 1 kHz loops (a setpoint
    latency no user knows): command_delay found, searched in steps of COMMAND_DELAY_STEP of a
    tick (half a tick, the other delays' step, would land at 0 or 0.5 ms); within one tick it
    is the twin's timing against the machine (analysis.timing): kept in the model and said in
    the notes, not named. The position's whole delay (the command's plus the recorded
    position's own, which has the same signature there and may be found beside it) within
    0.1 ms: the synthetic truth's own encoder steps (its sensors are not smoothed) put its
    effort about 0.1 ms apart from the fitting twin's."""
    nominal, run = _record(tmp_path, {"command_delay": {"delay_s": 3e-4}})
    d, doc, _ = diagnose(run, nominal)
    assert d.effects == ()
    said = [n for n in d.notes if n.startswith("the twin's timing against the machine: ")]
    assert any(("command_delay" in n or "position_delay" in n) for n in said), d.notes
    # beside it, a sensor delay of a fraction of a tick may stand in for the synthetic truth's
    # 0.2 ms current-loop lag (as on its record with nothing hidden): timing too
    delays = ("command_delay", "position_delay", "measurement_delay")
    assert all(any(name in n for name in delays) for n in said), d.notes
    step = record_search.COMMAND_DELAY_STEP * nominal.base_period()
    on_position = doc.get(COMMAND_DELAY_SLOT) + doc.get(POSITION_DELAY_SLOT)
    assert on_position == pytest.approx(3e-4, abs=1e-4 + step)
    assert d.after.fe_dev_rms_m < 0.4 * d.before.fe_dev_rms_m  # 15.2 -> 3.8 um


def test_a_cubic_interpolator_gets_setpoints_whose_velocities_are_their_slopes(tmp_path):
    """A drive that fine-interpolates a cubic through the NC points' positions and velocities
    (the truth machine's and its nominal twin's), on a 5 ms trace (five NC points per
    sample): the NC points between the samples are a smooth curve and its slopes
    (Twin._inputs). Interpolated linearly, position and velocity apart, the velocities were
    not the positions' slopes and the cubic wiggled between them (the effort 23 % off the
    machine's, 2 um position)."""
    from feed_twin.truth import Trace, make_record

    twin = Twin.compile(ModelDoc.load(ROOT / "config" / "truth_nominal.yaml"))
    assert twin.controller.config.position.interpolation == "cubic"
    rec = make_record(tmp_path / "run.csv", trace=Trace(period_s=0.005), seed=3)
    run = load_measured(rec.csv, rec.map)
    out = twin.simulate(drive_from_run(run), twin.nominal[None, :])
    effort = run["torque_cmd_Nm"]
    assert out.effort is not None
    assert np.linalg.norm(out.effort[0] - effort) < 0.05 * np.linalg.norm(effort)
    assert np.sqrt(np.mean((out.x_m[0] - run["pos_meas_m"]) ** 2)) < 1e-6


def test_phase_offsets_of_an_effort_source_twin_are_a_torque_ripple_on_its_rotor():
    """current_offset on the truth machine's nominal twin (a rotational EffortSource, 3 pole
    pairs): a CoggingTorque of order p on the source's flange, whose torque is -G dq with
    dq = -alpha sin(theta_e) + beta cos(theta_e) the offsets' q part (G = 0.45 N m/A); the
    edit's report reads back the offsets the truth set (no common part)."""
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    offsets = {"offset_a_A": 0.2, "offset_b_A": -0.05, "offset_c_A": -0.15}
    truth = BY_NAME["current_offset"].truth(doc, offsets)
    (name,) = truth.of_type("CoggingTorque")
    params = truth.component(name)["params"]
    assert params["order"] == 3
    alpha, beta = 0.2, (-0.05 + 0.15) / np.sqrt(3.0)
    for theta in np.linspace(0.0, 2.0 * np.pi, 7):
        dq = -alpha * np.sin(theta) + beta * np.cos(theta)
        torque = params["amplitude"] * np.sin(theta + params["phase"])
        assert torque == pytest.approx(-0.45 * dq, abs=1e-12)

    class Ripple:  # the ranking's weights of that ripple on the effort [N m]
        variant = ""
        coefficients = {"sin": -0.45 * alpha, "cos": 0.45 * beta}  # +G dq: the loop cancels
        residual_domain = "effort"
        force_per_unit = 2.0 * np.pi / 0.01  # [N per N m] through the 10 mm lead

    edit = BY_NAME["current_offset"].edit(doc, Ripple())  # type: ignore[arg-type]
    values = {p.name: p.initial for p in edit.own}
    assert [p.name.split(".")[1] for p in edit.own] == ["amplitude", "phase"]
    for key, value in offsets.items():
        assert edit.report[key](values) == pytest.approx(value, abs=1e-9)


@pytest.mark.slow
def test_phase_offsets_on_the_truth_machine_are_fitted_through_its_loops(tmp_path):
    """The truth machine's offsets enter its current loop: the rotor feels them as a torque
    ripple that its velocity loop cancels only below its bandwidth (the recorded current
    carries all of dq at a crawl, 28 % of it at 57 Hz electrical). Fitted as that torque
    ripple the offsets (no common part) come within 10 %; as a ripple on the record they came
    14-21 % small (benchmarks/blind_truth.py, before)."""
    from feed_twin.truth import make_record

    nominal = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    hidden = {"current_offset": {"offset_a_A": 0.15, "offset_b_A": -0.15, "offset_c_A": 0.15}}
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=5)
    d, _, _ = diagnose(load_measured(rec.csv, rec.map), nominal)
    found = {e.name: e.parameters for e in d.effects}
    assert list(found)[:1] == ["current_offset"], found
    # the common part (+0.05 A) is invisible in the rotor frame
    for x, truth in zip("abc", (0.1, -0.2, 0.1), strict=True):
        assert found["current_offset"][f"offset_{x}_A"] == pytest.approx(truth, abs=0.01)


def test_a_declared_mean_is_the_ramps_mean_over_each_period():
    """Analytic: a map that declares `trace_filter: mean` makes the twin record a ramp
    y = y0 + b t (base ticks h = 1 ms, 20 ms samples) as its mean over the period ending at
    each sample, y0 + b (t - 10 ms), the law of recorder.period_mean (a trace averages over
    time). The mean of the 20 ticks ending there, used before, lies b h / 2 later."""
    from feed_twin.analysis.twin import Drive

    twin = Twin.compile(ModelDoc.load(NOMINAL))
    h, dec, b = twin.base_period_s, 20, 0.15
    stamps = dec * h * np.arange(50)
    drive = Drive.at_rest(stamps, trace_mean=True)
    ramp = (0.2 + b * h * np.arange(50 * dec))[None, :]
    pos, eff, _ = twin._as_recorded(drive, dec, ramp, 2.0 * ramp, None, twin.record_slots(drive))
    expected = 0.2 + b * (stamps[1:] - 0.5 * dec * h)
    assert pos[0, 1:] == pytest.approx(expected, abs=1e-12)
    assert eff[0, 1:] == pytest.approx(2.0 * expected, abs=1e-12)


def test_a_command_rebuilt_from_its_period_means_is_the_command():
    """Analytic: x = a t^2 has the mean a (t^2 - t T + T^2 / 3) over the period T ending at t;
    recorder.deaveraged rebuilds x, its rate and second rate from those means on the twin's
    ticks (inside the record: the first window reaches back before it)."""
    from feed_twin.analysis.recorder import deaveraged

    a, period, h = 0.3, 0.02, 2.5e-4
    ticks = round(period / h)
    t = period * np.arange(1, 60)
    means = a * (t**2 - t * period + period**2 / 3.0)
    fine = t[0] + h * np.arange(ticks * len(t))
    x, v, acc = deaveraged(t, means, fine, ticks)
    inside = (fine > t[2]) & (fine < t[-3])
    assert x[inside] == pytest.approx(a * fine[inside] ** 2, abs=1e-9)
    assert v[inside] == pytest.approx(2.0 * a * fine[inside], abs=1e-7)
    assert acc[inside] == pytest.approx(np.full(inside.sum(), 2.0 * a), abs=1e-4)
