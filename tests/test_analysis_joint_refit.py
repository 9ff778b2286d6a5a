"""The final joint re-fit that runs to a model no feed axis has keeps the effect-by-effect fit
and says so (it crashed the workflow: the truth machine's axial E fitted to infinity)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from feed_twin.analysis import reexamine, rounds
from feed_twin.analysis.fit import FitResult, FreeParameter, SimOutputs
from feed_twin.analysis.model_doc import EFFORT_DELAY_SLOT
from feed_twin.analysis.reexamine import Found
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.rounds import Options, State, final_joint
from feed_twin.analysis.twin import ModelDoc, Twin

ROOT = Path(__file__).resolve().parents[1]


def _ran_off(stiffness: float) -> tuple[SimOutputs, FitResult]:
    """(outputs, a converged fit that ran the axial E to `stiffness` [Pa])."""
    outputs = SimOutputs(x_m=np.zeros((1, 3)), effort=np.zeros((1, 3)), ok=np.ones(1, bool))
    ran_off = FitResult(
        values={"axial.E": stiffness},
        cost_initial=1.0,
        cost=0.5,
        converged=True,
        message="converged",
        evaluations=3,
        outputs=outputs,
    )
    return outputs, ran_off


def test_a_joint_fit_to_an_infinite_stiffness_is_not_kept(monkeypatch):
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    twin = Twin.compile(doc)
    outputs, ran_off = _ran_off(math.inf)
    state = State(doc=doc, twin=twin, outputs=outputs, cost=1.0)
    monkeypatch.setattr(rounds, "fit_resumed", lambda *args, **kwargs: ran_off)
    monkeypatch.setattr(rounds, "joint_free", lambda state: [])
    note = final_joint(state, None, None, Options())  # type: ignore[arg-type]
    assert note is not None and "ran to a model no feed axis has" in note
    assert "plant.axial.E = inf" in note and "kept the effect-by-effect fit" in note
    assert state.doc is doc and state.cost == 1.0


def test_a_reexamination_whose_refit_runs_off_keeps_the_effect(monkeypatch):
    """Removing an effect and fitting the others again to a bearing stiffness of 3e61 N/m (the
    truth machine's current-offset record crashed the workflow so): no rival, None. The doc
    is the nominal twin with a 1 ms effort delay found, the stiffness another effect's."""
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    outputs, ran_off = _ran_off(3e61)
    monkeypatch.setattr(reexamine, "fit_resumed", lambda *args, **kwargs: ran_off)
    stiffness = FreeParameter(name="axial.E", initial=doc.get("axial.E"), scale=2.1e11)
    target = Found(
        effect=FoundEffect(
            name="channel_delay", evidence="", parameters={}, explained_fraction=0.1, component=""
        ),
        own=(),
        neutral={EFFORT_DELAY_SLOT: 0.0},
        at_discovery={EFFORT_DELAY_SLOT: 1e-3},
        report={},
        added=1,
    )
    other = dataclasses.replace(target, own=(stiffness,), neutral={}, at_discovery={})
    gone = reexamine.without(
        target,
        [other],
        doc.set(EFFORT_DELAY_SLOT, 1e-3),
        outputs,
        drive=None,  # type: ignore[arg-type]  # the re-fit is replaced
        meas=None,  # type: ignore[arg-type]
        channels=lambda out: {},
        max_evaluations=3,
    )
    assert gone is None
