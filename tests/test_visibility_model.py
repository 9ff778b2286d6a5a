"""What the record could show but the model cannot carry, said (analysis.visibility)."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.twin import Twin
from feed_twin.analysis.visibility import Unseen, _uncarried
from feed_twin.io.measured import MeasuredRun

ROOT = Path(__file__).resolve().parents[1]


def _run(**signals: np.ndarray) -> MeasuredRun:
    t = np.arange(0.0, 0.1, 1e-3)
    x = 0.2 + 0.01 * t
    return MeasuredRun(
        source="run",
        t_s=t,
        signals={"pos_cmd_m": x, "pos_meas_m": x, **signals},
        position_sensor="linear_scale",
    )


def test_dead_time_without_an_inverter_is_said_not_searched():
    doc = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    torque = {"torque_cmd_Nm": np.zeros(100)}
    # with the drive's data sheet the effect writes the electrical stage it acts on
    assert _uncarried(_run(**torque), Twin.compile(doc)) == []
    data = copy.deepcopy(doc.data)
    del data["analysis"]["drive_stage"]
    twin = Twin.compile(ModelDoc(data=data, source=doc.source, reference_gain=doc.reference_gain))
    (unseen,) = _uncarried(_run(**torque), twin)
    assert unseen.name == "dead_time" and unseen.by_model
    assert unseen.line().startswith(
        "not searched with this model: dead_time: the model drives its motor through an ideal "
        "current loop (no Inverter)"
    )
    # a record with the q-current: the ranking weighs it (and names it not fitted if it shows)
    assert _uncarried(_run(current_q_A=np.zeros(100)), twin) == []


def test_a_model_with_an_inverter_carries_the_dead_time():
    twin = Twin.compile(ModelDoc.load(ROOT / "config" / "axis_default.yaml"))
    assert _uncarried(_run(torque_cmd_Nm=np.zeros(100)), twin) == []


def test_a_record_side_line_keeps_its_words():
    assert Unseen(name="backlash", reason="below").line() == (
        "cannot be seen in this record: backlash: below"
    )


def test_the_verdict_says_what_was_not_searched():
    from feed_twin.analysis.verdict import Leftover, verdict

    left = [Leftover(channel="effort", unit="N m", rms=0.5, noise_ratio=100.0, signature="")]
    text = verdict([], [], left, unsearched=["dead_time"])
    assert text.startswith("no effect of the library is missing, but a residual"), text
    assert text.endswith("; not searched, the model cannot carry them: dead_time"), text
    quiet = [Leftover(channel="effort", unit="N m", rms=0.005, noise_ratio=1.0, signature="")]
    assert "not searched" not in verdict([], [], quiet, unsearched=["dead_time"])
