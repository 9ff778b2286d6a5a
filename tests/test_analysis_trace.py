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
from feed_twin.analysis.model_doc import EFFORT_DELAY_SLOT
from feed_twin.analysis.recorder import window_mean
from feed_twin.analysis.synthetic import generate, write_csv
from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
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


def test_a_trace_averaged_over_20_ms_is_modelled(tmp_path):
    """Every channel the mean over 20 ms, as controllers export their traces, with Coulomb
    friction hidden: the window is identified, the friction found, and the effort error is
    not left at a quarter (it was 26 % after a position delay alone stood for the window)."""
    nominal, run = _record(tmp_path, {"coulomb_friction": {"F_c_N": 15.0}}, window_ticks=20)
    d, _, _ = diagnose(run, nominal)
    found = {e.name: e.parameters for e in d.effects}
    assert found["trace_window"]["window_s"] == pytest.approx(0.020, abs=0.0015)
    assert found["coulomb_friction"]["F_c_N"] == pytest.approx(15.0, rel=0.1)
    assert d.before.effort_rel_err_pct is not None and d.after.effort_rel_err_pct is not None
    assert d.before.effort_rel_err_pct > 40.0
    assert d.after.effort_rel_err_pct < 3.0


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
