"""Helpers of the tests that run a twin on a made-up command or edit it by hand."""

from __future__ import annotations

from typing import Any

import numpy as np

from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.fit import SimOutputs
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.report import Diagnosis
from feed_twin.analysis.twin import Twin, drive_from_run
from feed_twin.io.measured import MeasuredRun


def simulate_command(doc: ModelDoc, t: np.ndarray, x_cmd: np.ndarray) -> SimOutputs:
    """The nominal twin of `doc` driven by the position command x_cmd [m] at times t [s]
    (a record whose measured position is the command: only its command drives the twin)."""
    run = MeasuredRun(
        source="command",
        t_s=t,
        signals={"pos_cmd_m": x_cmd, "pos_meas_m": x_cmd},
        position_sensor="linear_scale",
    )
    twin = Twin.compile(doc)
    out = twin.simulate(drive_from_run(run), twin.nominal[None, :])
    assert out.ok[0]
    return out


def strong_candidate(effect: str, coefficients: dict[str, float], **more: Any) -> Candidate:
    """A ranking's finding of library effect `effect` with these weights, far above the noise."""
    fields: dict[str, Any] = {
        "variant": "",
        "explained_fraction": 0.9,
        "f_statistic": 1e3,
        "p_value": 0.0,
        "n_eff": 1000.0,
        "significant": True,
    }
    return Candidate(effect=BY_NAME[effect], coefficients=coefficients, **(fields | more))


def assert_current_lag_taken_as_timing(d: Diagnosis) -> None:
    """On a synthetic EMPS record with nothing hidden: nothing named. The synthetic truth's
    unmodelled 0.2 ms current-loop lag left a position residual 13x the encoder's noise; a
    sensor delay of a fraction of the 1 ms tick (the loops reading their position between
    samples) now takes it, as the twin's timing: said, kept, not named. The stiffness's
    signature in the first residual (6.5 %, p = 0.0008), which this model cannot carry, is
    still said."""
    assert d.effects == (), d.notes
    timing = [n for n in d.notes if n.startswith("the twin's timing against the machine")]
    assert len(timing) == 1 and "measurement_delay +0.1" in timing[0], d.notes
    position = next(c for c in d.leftover if c["channel"] == "position")
    assert position["noise_ratio"] < 2.0 and not position["far_above_noise"], position
    assert d.after.fe_dev_rms_m < 0.2 * d.before.fe_dev_rms_m
    assert "position_dependent_stiffness, which could not be fitted" in d.verdict, d.verdict
