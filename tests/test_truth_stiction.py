"""Stiction on the independent truth machine (feed_twin.truth): a Karnopp table that sticks
below 10 um/s a fraction of a micrometre off its target, whose velocity loop's integrator then
winds the held force up until it breaks away. The seed is one the benchmark does not use
(benchmarks/blind_truth.py: 101-103)."""

from __future__ import annotations

from pathlib import Path

import pytest

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.io.measured import load_measured
from feed_twin.truth import draw_all, make_record

NOMINAL = Path(__file__).resolve().parents[1] / "config" / "truth_nominal.yaml"


@pytest.mark.slow  # a truth record and a whole diagnose: 3-5 s on a quiet host, 40 s loaded
def test_stiction_is_named_with_its_holding_force_on_a_truth_record(tmp_path: Path):
    """Named alone, its holding force (the data sheet's Coulomb force, which it takes over)
    within 5 %, and the effort error smaller after the fit."""
    hidden = draw_all(["stiction"], seed=7)
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=7)
    d = diagnose(load_measured(rec.csv, rec.map), ModelDoc.load(NOMINAL))[0]
    assert [e.name for e in d.effects] == ["stiction"], d.notes
    truth = hidden["stiction"]["F_hold_N"]
    assert d.effects[0].parameters["F_hold_N"] == pytest.approx(truth, rel=0.05)
    before, after = d.before.effort_rel_err_pct, d.after.effort_rel_err_pct
    assert before is not None and after is not None and after < before
