"""The final joint re-fit that runs to a model no feed axis has keeps the effect-by-effect fit
and says so (it crashed the workflow: the truth machine's axial E fitted to infinity)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from feed_twin.analysis import rounds
from feed_twin.analysis.fit import FitResult, SimOutputs
from feed_twin.analysis.rounds import Options, State, final_joint
from feed_twin.analysis.twin import ModelDoc, Twin

ROOT = Path(__file__).resolve().parents[1]


def test_a_joint_fit_to_an_infinite_stiffness_is_not_kept(monkeypatch):
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    twin = Twin.compile(doc)
    outputs = SimOutputs(x_m=np.zeros((1, 3)), effort=np.zeros((1, 3)), ok=np.ones(1, bool))
    state = State(doc=doc, twin=twin, outputs=outputs, cost=1.0)
    ran_off = FitResult(
        values={"axial.E": math.inf},
        cost_initial=1.0,
        cost=0.5,
        converged=True,
        message="converged",
        evaluations=3,
        outputs=outputs,
    )
    monkeypatch.setattr(rounds, "fit", lambda *args, **kwargs: ran_off)
    monkeypatch.setattr(rounds, "joint_free", lambda state: [])
    note = final_joint(state, None, None, Options())  # type: ignore[arg-type]
    assert note is not None and "ran to a model no feed axis has" in note
    assert "plant.axial.E = inf" in note and "kept the effect-by-effect fit" in note
    assert state.doc is doc and state.cost == 1.0
