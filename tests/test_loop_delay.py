"""measurement_delay delays what the loops read, not a scale that only records."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
from twin_support import strong_candidate

from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.plant.sensors import MAX_DELAY_TICKS, SEARCHED_DELAY_S, SEARCHED_DELAY_TICKS

ROOT = Path(__file__).resolve().parents[1]
DELAY = BY_NAME["measurement_delay"]


def _tied(path: Path) -> tuple[str, ...]:
    doc = ModelDoc.load(path)
    edit = DELAY.edit(doc, strong_candidate("measurement_delay", {}))
    assert [p.name for p in edit.own] == ["sensors.delay_ticks"]
    # searched first over 5 ms and at least 8 ticks (as far as the engine keeps), then on
    # while the best is at the edge
    ticks = math.ceil(SEARCHED_DELAY_S / doc.base_period() - 1e-9)
    assert edit.grid == tuple(range(min(MAX_DELAY_TICKS, max(SEARCHED_DELAY_TICKS, ticks)) + 1))
    assert edit.own[0].upper == MAX_DELAY_TICKS
    assert edit.refine  # a fraction of a tick is interpolated: the best tick is refined
    return model_of(edit.doc).tie_members("sensors.delay_ticks")


def test_a_drives_tick_searches_5_ms_first():
    """At the truth machine's 0.25 ms tick the first grid is 21 ticks (5 ms), not 8 (2 ms:
    its 4 ms feedback delay was fitted as the 2 ms at the grid's edge)."""
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    edit = DELAY.edit(doc, strong_candidate("measurement_delay", {}))
    assert edit.grid == tuple(range(21))


def test_a_semi_closed_loop_delays_its_encoder_and_records_the_scale_on_time():
    # config/truth_nominal.yaml: the position loop on the motor encoder, a scale that records
    assert _tied(ROOT / "config" / "truth_nominal.yaml") == ("encoder.delay_ticks",)
    doc = DELAY.truth(ModelDoc.load(ROOT / "config" / "truth_nominal.yaml"), {"delay_ticks": 3})
    assert (doc.get("encoder.delay_ticks"), doc.get("scale.delay_ticks")) == (3, 0)
    # a delay in seconds (the truth machine's, feed_twin.truth) in the twin's ticks (0.25 ms:
    # the drive's velocity-loop period)
    doc = DELAY.truth(ModelDoc.load(ROOT / "config" / "truth_nominal.yaml"), {"delay_s": 2e-3})
    assert doc.base_period() == 2.5e-4
    assert doc.get("encoder.delay_ticks") == 8


def test_a_loop_closed_on_the_scale_delays_both_sensors_it_reads():
    # config/axis_default.yaml: position on the scale, speed on the motor encoder
    assert set(_tied(ROOT / "config" / "axis_default.yaml")) == {
        "encoder.delay_ticks",
        "scale.delay_ticks",
    }


@pytest.mark.slow
def test_a_feedback_delay_beyond_the_grid_is_searched_on_until_it_is_inside(tmp_path):
    """The truth machine's loops read their position 4 ms late (16 of the twin's 0.25 ms
    ticks, beyond the 15 the engine kept). Searched from a grid of 0-4 ticks, the search goes
    on while its best lies at the edge (to 8, 16, 32 ticks) and finds the 16 (a fixed grid of
    8 ticks named 2 ms for 4 ms), then refines it between whole ticks."""
    from feed_twin.analysis.channels import noise_floors, weighted_channels
    from feed_twin.analysis.trials import grid_search
    from feed_twin.analysis.twin import Twin, drive_from_run
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import make_record

    nominal = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    rec = make_record(tmp_path / "run.csv", hidden={"measurement_delay": {"delay_s": 4e-3}}, seed=5)
    run = load_measured(rec.csv, rec.map)
    edit = DELAY.edit(nominal, strong_candidate("measurement_delay", {}))
    twin = Twin.compile(model_of(edit.doc))
    drive = drive_from_run(run)
    out = twin.simulate(drive, twin.nominal[None, :])
    meas = weighted_channels(run, out, 1, noise_floors(run, out))
    narrow = dataclasses.replace(edit, grid=tuple(range(5)))
    found = grid_search(twin, narrow, drive, meas)
    # the best whole tick, 16, refined between 15 and 17 (trials.refined): the truth
    # machine's loops are not the twin's, and its 4 ms are the twin's 16.3 ticks (4.08 ms)
    assert abs(found.values["sensors.delay_ticks"] - 16.0) < 0.5
    assert found.message.startswith("grid search over 33 values, refined to ")
    assert found.evaluations > 33
