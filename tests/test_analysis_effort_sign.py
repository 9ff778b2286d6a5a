"""The effort's sign: decided by fitting the nominal twin's effort with both signs, not by a
correlation threshold (a weight or friction the twin lacks hides a reversed sign from it)."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.analysis.effort_sign import REVERSED_FIT_RATIO, check_effort_sign, sign_fits
from feed_twin.analysis.fit import SimOutputs
from feed_twin.io.measured import MeasuredDataError, MeasuredRun

MASS_KG = 100.0
WEIGHT_N = -1200.0  # a vertical axis's weight, which the nominal twin lacks
FRICTION_N = 300.0  # sliding friction the nominal twin lacks, larger than its inertial force


def _record(sign: float, *, twin_scale: float = 1.0) -> tuple[MeasuredRun, SimOutputs, np.ndarray]:
    """Back-and-forth moves; the twin's effort is the inertial force alone, the machine's adds
    a weight and sliding friction and is recorded with `sign`."""
    t = np.arange(0.0, 4.0, 1e-3)
    x = 0.05 * np.sin(2.0 * np.pi * 0.5 * t) ** 3
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    twin = MASS_KG * a
    noise = np.random.default_rng(3).normal(0.0, 5.0, len(t))
    sliding = np.tanh(v / (0.002 * np.max(np.abs(v))))
    machine = twin_scale * twin + WEIGHT_N + FRICTION_N * sliding + noise
    run = MeasuredRun(
        source="trace.csv",
        t_s=t,
        signals={"pos_meas_m": x, "force_cmd_N": sign * machine},
        position_sensor="motor_encoder",
    )
    out = SimOutputs(x_m=x[None, :], effort=twin[None, :], ok=np.ones(1, dtype=bool))
    return run, out, twin


def test_a_reversed_sign_that_the_correlation_missed_is_one_line():
    run, out, twin = _record(-1.0)
    r = float(np.corrcoef(run["force_cmd_N"], twin)[0, 1])
    assert -0.5 < r < 0.0  # the old threshold (-0.5) stayed silent
    as_recorded, reversed_ = sign_fits(run, twin)
    assert as_recorded > 100.0 * reversed_
    with pytest.raises(MeasuredDataError) as err:
        check_effort_sign(run, out)
    message = str(err.value)
    assert message.startswith("trace.csv: the measured force_cmd_N fits the nominal twin's ")
    assert "better with its sign reversed (RMS left " in message
    # what the reversed fit leaves is the record's noise (5 N)
    left = float(message.split("RMS left ")[1].split(" N")[0])
    assert left == pytest.approx(5.0, rel=0.1)
    assert message.endswith("its sign looks reversed; give its column a negative gain in the map")
    assert len(message.splitlines()) == 1


def test_the_sign_as_recorded_passes_whatever_the_scale():
    # a torque constant known only to a factor of 3 is the scale's business, not the sign's
    for scale in (0.3, 1.0, 3.0):
        run, out, twin = _record(1.0, twin_scale=scale)
        check_effort_sign(run, out)


def test_an_effort_the_twin_does_not_explain_is_not_called_reversed():
    run, out, twin = _record(1.0, twin_scale=0.0)
    as_recorded, reversed_ = sign_fits(run, twin)
    assert as_recorded <= REVERSED_FIT_RATIO * reversed_
    check_effort_sign(run, out)
