"""The joint selection after the rounds (analysis.joint), on the independent truth machine
(feed_twin.truth) with seeds the benchmarks do not use (benchmarks/blind_truth.py: 101-103)."""

from __future__ import annotations

from pathlib import Path

import pytest

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.report import markdown
from feed_twin.io.measured import load_measured
from feed_twin.truth import draw_all, make_record

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "truth_nominal.yaml"


@pytest.mark.slow
def test_a_heavier_slide_is_a_mass_not_a_drive_gain(tmp_path: Path):
    """A weight, more Coulomb friction and a slide 172 kg heavier: the rounds take a drive gain
    (it scales every force) first, then the weight, then a viscous term for the Coulomb force
    the gain scaled wrong (with the drive's current loop in the twin the gain matches the
    heavier slide's inertia, so no acceleration is left for the mass). The mass in the gain's
    place alone leaves the Coulomb force unexplained; the joint selection fits the best effect
    of that set's residual in as well (a Coulomb force), prunes the viscous term, and keeps the
    set: every size within 10 %. About 20 s on a quiet host."""
    hidden = draw_all(["constant_force", "coulomb_friction", "mass_error"], seed=2)
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=2)
    d = diagnose(load_measured(rec.csv, rec.map), ModelDoc.load(NOMINAL))[0]
    found = {e.name: e.parameters for e in d.effects}
    assert set(found) == set(hidden), d.notes
    for name, truth in hidden.items():
        for key, value in truth.items():
            assert found[name][key] == pytest.approx(value, rel=0.10), (name, key)
    swap = [n for n in d.notes if n.startswith("joint selection:")]
    assert swap and "in place of torque_constant_error" in swap[0], d.notes
    assert "mass_error" in swap[0] and "coulomb_friction" in swap[0], d.notes
    assert d.search["joint_trials"] >= 1 and d.search["joint_simulations"] > 0
    assert d.search["simulations"] > d.search["joint_simulations"]
    text = markdown(d, [])
    assert "of which the joint selection (analysis.joint) fitted" in text
