"""The fitted model as written: a fitted drive gain survives the round trip through model.yaml."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import load_measured
from feed_twin.sim.config import load_axis_config

ROOT = Path(__file__).resolve().parents[1]
EMPS = Path("/work/shared/data/emps")


def test_a_fitted_gain_keeps_the_records_conversion_through_model_yaml(tmp_path):
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    slot = nominal.gain_slot()
    assert slot is not None, "emps_nominal.yaml's drive has a gain"
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


@pytest.mark.slow
def test_simulate_on_the_written_model_reproduces_the_fitted_torque_constant(tmp_path, capsys):
    """diagnose fits a torque-constant error; `simulate --config out/model.yaml` on the same
    record then gives the fit's effort error, not the nominal's (the issue: it gave a worse one
    than the nominal, the fitted gain converted the record's effort a second time)."""
    from feed_twin.analysis.compare import relative_error_pct
    from feed_twin.analysis.synthetic import generate, write_csv
    from feed_twin.cli import main

    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    csv = tmp_path / "run.csv"
    map_path = write_csv(
        csv, generate(nominal, {"torque_constant_error": {"gain": 29.88}}), nominal
    )
    out = tmp_path / "out"
    code = main(["diagnose", str(csv), "--config", str(nominal.source), "--map", str(map_path),
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert [e["name"] for e in report["effects"]] == ["torque_constant_error"]
    after = report["after"]["effort_rel_err_pct"]
    assert after < 0.2 * report["before"]["effort_rel_err_pct"]
    traces = tmp_path / "traces.csv"
    code = main(["simulate", "--config", str(out / "model.yaml"), "--measured", str(csv),
                 "--map", str(map_path), "--out", str(traces)])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    data = np.genfromtxt(traces, delimiter=",", names=True)
    again = relative_error_pct(data["force_cmd_N"], data["sim_force_cmd_N"])
    assert again == pytest.approx(after, rel=1e-6, abs=1e-6)
