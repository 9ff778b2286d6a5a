"""Helpers of the tests that run a twin on a made-up command or edit it by hand."""

from __future__ import annotations

from typing import Any

import numpy as np

from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.fit import SimOutputs
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.ranking import Candidate
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
