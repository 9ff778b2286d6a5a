"""The fitted model as written: a fitted drive gain survives the round trip through model.yaml."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.io.config import ConfigError
from feed_twin.io.measured import load_measured
from feed_twin.sim.config import load_axis_config

ROOT = Path(__file__).resolve().parents[1]
EMPS = Path("/work/shared/data/emps")


def test_a_fitted_gain_keeps_the_records_conversion_through_model_yaml(tmp_path):
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    slot = nominal.gain_slot()
    fitted = nominal.set(slot, 0.85 * nominal.get(slot))  # a torque-constant error, fitted
    fitted.dump(tmp_path / "model.yaml", ["fitted"])
    again = ModelDoc.load(tmp_path / "model.yaml")
    assert again.reference_gain == nominal.reference_gain
    assert again.get(slot) == pytest.approx(0.85 * nominal.get(slot), rel=1e-12)
    run = load_measured(EMPS / "DATA_EMPS.csv", ROOT / "config" / "emps_map.yaml")
    drive = drive_from_run(run)
    before = Twin.compile(fitted).simulate(drive, Twin.compile(fitted).nominal[None, :])
    twin = Twin.compile(again)
    after = twin.simulate(drive, twin.nominal[None, :])
    np.testing.assert_array_equal(after.effort, before.effort)
    # the unchanged model writes no such section
    nominal.dump(tmp_path / "plain.yaml", ["nominal"])
    assert "analysis" not in (tmp_path / "plain.yaml").read_text()


def test_the_section_is_checked_and_known_to_the_axis_loader(tmp_path):
    text = (ROOT / "config" / "emps.yaml").read_text()
    path = tmp_path / "m.yaml"
    path.write_text(text + "analysis: {effort_reference_gain: 35.15}\n")
    load_axis_config(path)  # the engine's loader accepts the section
    path.write_text(text + "analysis: {effort_reference_gain: 0}\n")
    with pytest.raises(ConfigError, match=r"analysis.effort_reference_gain = 0: must be a finite"):
        ModelDoc.load(path)
