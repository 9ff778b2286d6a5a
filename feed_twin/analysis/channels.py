"""The discrepancy workflow's channels: the recorded effort, position and q-voltage residuals
(measured minus twin) and the weights the fit gives them.

A channel's weight is its noise level estimated at the current model (the RMS of its residual
there, the maximum-likelihood variance), floored by its sample noise (analysis.significance), so
a channel that one large effect explained keeps its say. analysis.rounds estimates the weights
again before every round.
"""

from __future__ import annotations

import math

import numpy as np

from feed_twin.analysis.fit import Measured, SimOutputs
from feed_twin.analysis.significance import sample_noise
from feed_twin.io.measured import MeasuredRun

VOLTAGE_Q = "voltage_q_V"  # the canonical signal of the current controller's q-voltage
# gaps between a channel's values below this share of its largest are the number format's
# rounding (a CSV's 10 significant digits), not the record's step
QUANTISATION_RELATIVE = 1e-8
REPEATED_SHARE = 0.9  # a rounded channel takes fewer distinct values than this share of samples
# ... or, moving, changes between samples by many of its steps: a step below this share of its
# median change is the record's rounding, not the spacing of a ramp's values
FINE_STEP = 0.1


def _from(r: np.ndarray, start: int) -> np.ndarray:
    """The residual with its first `start` samples, which are not evidence, set to zero (the
    record's time base is kept: the effects' signatures and supports index it)."""
    if start == 0:
        return r
    r = r.copy()
    r[:start] = 0.0
    return r


def residuals(run: MeasuredRun, out: SimOutputs, row: int = 0, *, start: int = 0):
    """(effort, position) residuals, twin minus measured for the position; zero before the
    first sample that is evidence (`start`, Twin.first_evidence)."""
    rp = out.x_m[row] - run["pos_meas_m"]
    if run.position_offset_free:
        rp = rp - float(np.mean(rp[start:]))  # the zero the record does not give
    rp = _from(rp, start)
    re = None
    name = run.effort_name
    if name is not None and out.effort is not None:
        re = _from(run[name] - out.effort[row], start)
        if run.effort_blind is not None:
            re = np.where(run.effort_blind, 0.0, re)  # no evidence there (analysis.visibility)
    return re, rp


def voltage_residual(
    run: MeasuredRun, out: SimOutputs, row: int = 0, *, start: int = 0
) -> np.ndarray | None:
    """Measured minus twin q-voltage [V] of the current controller, when both have it."""
    if VOLTAGE_Q not in run or out.voltage_q is None:
        return None
    return _from(run[VOLTAGE_Q] - out.voltage_q[row], start)


def channel_residuals(
    run: MeasuredRun, out: SimOutputs, row: int = 0, *, start: int = 0
) -> dict[str, np.ndarray]:
    """Each recorded channel's residual (measured minus twin) on the record's time base, zero
    before the first sample that is evidence."""
    re, rp = residuals(run, out, row, start=start)
    ru = voltage_residual(run, out, row, start=start)
    found = {"effort": re, "position": -rp, "voltage": ru}
    return {k: v for k, v in found.items() if v is not None}


def quantisation_step(y: np.ndarray) -> float:
    """The step a recorded channel is rounded to (a scale's resolution, a current's ADC count,
    a trace's display digits): the smallest gap between the values it takes, where every value
    lies on that step's grid and values repeat (a rounded channel dwells on its counts) or the
    channel moves by many steps from sample to sample (FINE_STEP: a 1 kHz trace of a table
    that rests a fifth of the time, in 10 nm steps, takes 97 % distinct values); 0 for a
    channel that is not rounded (a smooth ramp's equal gaps are no step)."""
    y = np.asarray(y, dtype=float)
    values = np.unique(y)
    if len(values) < 2:
        return 0.0
    gaps = np.diff(values)
    gaps = gaps[gaps > QUANTISATION_RELATIVE * float(np.max(np.abs(values)))]
    if not len(gaps):
        return 0.0
    q = float(gaps.min())
    # the step read off the whole span (the smallest gap carries the values' float noise, which
    # 3e7 steps of 10 nm over 0.3 m would add up to a fifth of a step)
    span = float(values[-1] - values[0])
    q = span / max(round(span / q), 1)
    counts = (values - values[0]) / q
    if float(np.mean(np.abs(counts - np.round(counts)) < 1e-3)) < 0.99:
        return 0.0
    if len(values) <= REPEATED_SHARE * len(y):
        return q
    changes = np.abs(np.diff(y))
    changes = changes[changes > 0.5 * q]
    return q if len(changes) and q < FINE_STEP * float(np.median(changes)) else 0.0


def noise_floors(run: MeasuredRun, out: SimOutputs, *, start: int = 0) -> dict[str, float]:
    """Each channel's sample noise: the least its weight's noise level can be (see
    analysis.significance), never below the smallest step that means anything in its unit, nor
    below the rounding noise of the record's own step, q / sqrt(12) (a channel that rests
    between two counts has no sample-to-sample noise, and its rounding is not an effect)."""
    least = {"effort": 1e-9, "position": 1e-12, "voltage": 1e-6}
    recorded = {"effort": run.effort_name, "position": "pos_meas_m", "voltage": VOLTAGE_Q}
    found = channel_residuals(run, out, start=start)
    floors = {}
    for k, r in found.items():
        name = recorded[k]
        rounding = 0.0 if name is None else quantisation_step(run[name]) / math.sqrt(12.0)
        floors[k] = max(sample_noise(r[start:]), least[k], rounding)
    return floors


def weighted_channels(
    run: MeasuredRun, out: SimOutputs, stride: int, floors: dict[str, float], *, start: int = 0
) -> Measured:
    """The fit's channels from the first sample that is evidence (`start`), each weighted by
    its noise level estimated at the model `out`: the RMS of its residual there, floored by its
    sample noise (analysis.significance)."""
    seen = 1.0 if run.effort_blind is None else max(float(np.mean(~run.effort_blind[start:])), 1e-3)
    sigma = {
        k: max(
            float(np.sqrt(np.mean(r[start:] ** 2) / (seen if k == "effort" else 1.0))), floors[k]
        )
        for k, r in channel_residuals(run, out, start=start).items()
    }
    name = run.effort_name
    return Measured(
        x_m=run["pos_meas_m"],
        effort=None if name is None or out.effort is None else run[name],
        scale_x=sigma["position"],
        scale_effort=sigma.get("effort", 1.0),
        stride=stride,
        start=start,
        voltage_q=run[VOLTAGE_Q] if "voltage" in sigma else None,
        scale_voltage=sigma.get("voltage", 1.0),
        free_offset=run.position_offset_free,
        effort_weight=None if run.effort_blind is None else (~run.effort_blind).astype(float),
    )
