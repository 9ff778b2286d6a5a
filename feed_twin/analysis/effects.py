"""The library of effects a twin may miss: the plant's declared effects plus the record's own.

Each effect is declared by the plant component that carries it (feed_twin.plant.effect_api.
Effect in the component's `EFFECTS`, collected by feed_twin.plant.registry): its signature (a
small set of regressors, functions of the measured motion, that the residual it causes would
follow; feed_twin.analysis.ranking projects residuals onto them and tests them), the edit of
the component's own parameters and the synthetic truth. This module adds the one effect that is
no part of the machine but of the record (the trace between machine and file: channel_delay,
position_delay, trace_window; searched over ranges the record sets, analysis.record_search) and
orders the library.

Domains: force-like effects act on the drive effort; position-like effects (sensor delay, lead
error, backlash with a linear scale, thermal growth) act on the measured position. The
inverter's dead time acts on the voltage: it is ranked on the q-axis voltage the current
controller commands, when the record has it, and falls back to the effort otherwise.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from feed_twin.analysis.drive_stage import dead_time_edit, expand, expandable
from feed_twin.analysis.model_doc import (
    ANALYSIS_SECTION,
    COMMAND_DELAY_SLOT,
    EFFORT_DELAY_SLOT,
    POLE_PAIRS_KEY,
    POSITION_DELAY_SLOT,
    RIPPLE_SLOTS,
    TRACE_WINDOW_SLOT,
    model_of,
)
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Weights,
    effort_rate,
    last_direction,
    make_edit,
    motion_from_position,
    moving,
)
from feed_twin.plant.pmsm import cogging_edit, rotor_source, with_cogging
from feed_twin.plant.registry import EFFECTS

# re-exported for the workflow's modules and the benchmarks (defined in plant.effect_api)
__all__ = [
    "BY_NAME",
    "LIBRARY",
    "RECORD_EFFECTS",
    "Effect",
    "Motion",
    "last_direction",
    "motion_from_position",
    "moving",
]

# delays of the recorded effort behind the position searched for channel_delay: +/- this many
# base periods in half steps (a trace recorder's channels drift by milliseconds)
CHANNEL_DELAY_PERIODS = 20


def _delay_grid(doc: Document) -> tuple[float, ...]:
    """The delays [s] an edit declares: +/- CHANNEL_DELAY_PERIODS base periods in half steps
    (analysis.record_search widens the range to what the record needs)."""
    period = doc.base_period()
    n = 2 * CHANNEL_DELAY_PERIODS
    return tuple(0.5 * period * k for k in range(-n, n + 1))


def _record_delay_edit(doc: Document, slot: str) -> Edit:
    """A recorded channel stamped later (or earlier) than the rest: not a change of the
    machine, a shift of the twin's output before it is compared (Twin.record_slots), searched
    over a grid and kept in the model's `analysis` section."""
    doc = doc.set(slot, doc.get(slot))
    own = [FreeParameter(name=slot, initial=doc.get(slot), scale=doc.base_period())]
    report = {"delay_s": lambda v: v[slot]}
    return make_edit(doc, own, report, interacts=False, grid=_delay_grid(doc))


def _channel_delay_edit(doc: Document, cand: Weights) -> Edit:
    del cand
    return _record_delay_edit(doc, EFFORT_DELAY_SLOT)


def _command_delay_edit(doc: Document, cand: Weights) -> Edit:
    del cand
    return _record_delay_edit(doc, COMMAND_DELAY_SLOT)


def _position_delay_edit(doc: Document, cand: Weights) -> Edit:
    del cand
    return _record_delay_edit(doc, POSITION_DELAY_SLOT)


def _trace_window_edit(doc: Document, cand: Weights) -> Edit:
    """The trace's averaging window [s], searched from one base tick (samples taken, not
    averaged) up (analysis.record_search); the grid declared is its first ticks."""
    del cand
    period = doc.base_period()
    # not set here: without it the twin averages as the column map says (Twin.record_slots)
    own = [FreeParameter(name=TRACE_WINDOW_SLOT, initial=doc.get(TRACE_WINDOW_SLOT), scale=period)]
    report = {"window_s": lambda v: v[TRACE_WINDOW_SLOT]}
    grid = tuple(sorted({doc.get(TRACE_WINDOW_SLOT), *(period * k for k in range(1, 41))}))
    return make_edit(doc, own, report, interacts=False, grid=grid)


def _position_rate(m: Motion) -> dict[str, np.ndarray]:
    """The signature of a delay of the recorded position: x(t - d) is x(t) - d v(t)."""
    return {"velocity": m.v_m_s}


def _window_rates(m: Motion) -> dict[str, np.ndarray]:
    """The signature of the trace's other mode (each sample the mean over its period, or taken
    as it is), ranked on the effort: the twin's effort as that mode records it less as it is
    recorded now (Motion.effort_other_mode). On the position (ranked there before) the window's
    lag (w/2) v is the command's lag too where the command is a mean alike, and nothing is left
    once the twin reads the command off a smooth curve: the truth machine's undeclared 20 ms
    mean lagged 3 um, while the window removed 93 % of the effort error. A record without
    effort: the position's mean over [t - w, t], x - (w/2) v + (w^2/6) a to second order."""
    if m.effort_sim is None:
        return {"velocity": m.v_m_s, "acceleration": m.a_m_s2}
    if m.effort_other_mode is None:  # the record's period is the twin's tick: no other mode
        return {"other_mode": np.zeros_like(m.effort_sim)}
    return {"other_mode": m.effort_other_mode - m.effort_sim}


def _slot_truth(slot: str, key: str):
    return lambda doc, p: doc.set(slot, p[key])


# effects of the record, not of the machine: no component carries them
RECORD_EFFECTS = (
    Effect(
        name="channel_delay",
        domain="effort",
        words="the recorder stamps the effort later (or earlier) than the position: the "
        "effort follows the twin's shifted in time while the following error does not move",
        parameters="the record: analysis.effort_delay_s (trace side, outside every loop)",
        needs=("effort_sim",),
        signature=effort_rate,
        edit=_channel_delay_edit,
        truth=_slot_truth(EFFORT_DELAY_SLOT, "delay_s"),
    ),
    Effect(
        name="command_delay",
        domain="position",
        words="the drive follows the recorded command later (or earlier) than the twin's "
        "loops do (its setpoint latency): position and effort both follow the twin's shifted "
        "in time",
        parameters="the record: analysis.command_delay_s (command side, before every loop)",
        signature=_position_rate,
        edit=_command_delay_edit,
        truth=_slot_truth(COMMAND_DELAY_SLOT, "delay_s"),
    ),
    Effect(
        name="position_delay",
        domain="position",
        words="the recorder stamps the position later (or earlier) than the command: the "
        "position residual follows the velocity, while the effort does not move",
        parameters="the record: analysis.position_delay_s (trace side, outside every loop)",
        signature=_position_rate,
        edit=_position_delay_edit,
        truth=_slot_truth(POSITION_DELAY_SLOT, "delay_s"),
    ),
    Effect(
        name="trace_window",
        domain="effort",
        words="the trace averages each channel over a window (a controller's trace filter): "
        "the recorded position lags by half the window, the effort's peaks are cut",
        parameters="the record: analysis.trace_window_s (trace side, outside every loop)",
        signature=_window_rates,
        fallback="position",
        edit=_trace_window_edit,
        truth=_slot_truth(TRACE_WINDOW_SLOT, "window_s"),
    ),
)


def _ripple_edit(doc: Document, cand: Weights) -> Edit:
    """Offsets on the drive's phase-current sensors in a twin without a CurrentSensor (an
    effort source): the ripple they leave in the recorded effort, once per electrical
    revolution, as the record's own (Twin.record_slots). The loop makes the true current
    differ from the measured by the offsets' q part and adds it back to its command, so the
    recorded effort carries it: -alpha sin + beta cos in the effort's unit (plant.sensors).
    Reported as the three phase offsets with no common part, in the recorded current's unit
    (the effort over the drive gain the record was converted with)."""
    s, c = (cand.coefficients.get(k, 0.0) for k in ("sin", "cos"))
    scale = max(math.hypot(s, c), 1e-9)
    for slot, value in zip(RIPPLE_SLOTS, (s, c), strict=True):
        doc = doc.set(slot, value)
    own = [FreeParameter(name=slot, initial=doc.get(slot), scale=scale) for slot in RIPPLE_SLOTS]
    gain = model_gain(doc)

    def phase(k: int):
        def value(v: dict[str, float]) -> float:
            return _phases(-v[RIPPLE_SLOTS[0]] / gain, v[RIPPLE_SLOTS[1]] / gain)[k]

        return value

    report = {f"offset_{x}_A": phase(k) for k, x in enumerate("abc")}
    # searched (analysis.record_search: linear in the record), not by the engine's fit
    return make_edit(doc, own, report, interacts=False, grid=(0.0,))


def model_gain(doc: Document) -> float:
    """The drive gain the record's effort was converted with (1 where none)."""
    gain = getattr(doc, "reference_gain", None)
    return float(gain) if gain else 1.0


def _offset_torque_edit(doc: Document, cand: Weights, pole_pairs: int) -> Edit:
    """Offsets on the drive's phase-current sensors in a twin whose motor is a rotational
    EffortSource: the torque ripple they make on the rotor. The drive's current loop holds the
    MEASURED q current at its command, so the true one is off by the offsets' q part
    dq = -alpha sin(theta_e) + beta cos(theta_e) (plant.sensors), and the rotor feels
    -G dq (G the source's torque per ampere): a CoggingTorque of order p on the source's flange,
    A sin(p phi + psi) = G (alpha sin - beta cos), reported as the three phase offsets with no
    common part, alpha = A cos(psi) / G, beta = -A sin(psi) / G. The velocity loop cancels
    that torque only below its bandwidth, so the recorded current carries dq whole at a crawl
    but not at speed (the truth machine's: 28 % of it at 57 Hz electrical, 40 deg late): taken
    as a ripple on the record (_ripple_edit) the offsets came out 13-20 % small."""
    gain = doc.get(f"{rotor_source(doc)}.gain")
    edit = cogging_edit(doc, cand, pole_pairs)
    amplitude, phase = (p.name for p in edit.own)

    def offset(k: int):
        def value(v: dict[str, float]) -> float:
            alpha = v[amplitude] * math.cos(v[phase]) / gain
            beta = -v[amplitude] * math.sin(v[phase]) / gain
            return _phases(alpha, beta)[k]

        return value

    report = {f"offset_{x}_A": offset(k) for k, x in enumerate("abc")}
    return dataclasses.replace(edit, report=report)


def _phases(alpha: float, beta: float) -> tuple[float, float, float]:
    """Phase offsets (a, b, c) with no common part whose alpha/beta parts are these."""
    root = 0.5 * math.sqrt(3.0)
    return alpha, -0.5 * alpha + root * beta, -0.5 * alpha - root * beta


def _offset_torque_truth(doc: Document, p: Mapping[str, float], pole_pairs: int) -> Document:
    """The torque ripple of phase offsets (_offset_torque_edit) on the source's flange."""
    a, b, c = (p[f"offset_{x}_A"] for x in "abc")
    alpha, beta = 2.0 / 3.0 * (a - 0.5 * (b + c)), (b - c) / math.sqrt(3.0)
    gain = doc.get(f"{rotor_source(doc)}.gain")
    amplitude, phase = gain * math.hypot(alpha, beta), math.atan2(-beta, alpha)
    return with_cogging(doc, pole_pairs, amplitude, phase)[0]


def _or_ripple(effect: Effect) -> Effect:
    """current_offset, carried by the model's CurrentSensor, else as the torque ripple on the
    rotor of an effort-source twin (_offset_torque_edit), else by the record (_ripple_edit): in
    a twin without a sensor the ripple of the offsets was named cogging torque."""

    def carrier(doc: Document) -> str:
        pole_pairs = (doc.data.get(ANALYSIS_SECTION) or {}).get(POLE_PAIRS_KEY)
        if doc.of_type("CurrentSensor") or pole_pairs is None:
            return "sensor"  # the sensor's offsets, or its LookupError
        try:
            rotor_source(doc)
        except LookupError:
            return "record"
        return "rotor"

    def edit(doc: Document, cand: Weights) -> Edit:
        where = carrier(doc)
        if where == "rotor":
            return _offset_torque_edit(doc, cand, doc.data[ANALYSIS_SECTION][POLE_PAIRS_KEY])
        return effect.edit(doc, cand) if where == "sensor" else _ripple_edit(doc, cand)

    def truth(doc: Document, p: Mapping[str, float]) -> Document:
        if carrier(doc) == "rotor":
            return _offset_torque_truth(doc, p, doc.data[ANALYSIS_SECTION][POLE_PAIRS_KEY])
        return effect.truth(doc, p)

    return dataclasses.replace(effect, edit=edit, truth=truth)


def _or_drive_stage(effect: Effect) -> Effect:
    """dead_time, carried by the model's Inverter, else, in a torque-source twin that gives its
    drive's data sheet, by the electrical stage analysis.drive_stage writes for it."""

    def edit(doc: Document, cand: Weights) -> Edit:
        if expandable(model_of(doc)):
            return dead_time_edit(model_of(doc), cand, effect.edit)
        return effect.edit(doc, cand)

    def truth(doc: Document, p: Mapping[str, float]) -> Document:
        return effect.truth(expand(model_of(doc)) if expandable(model_of(doc)) else doc, p)

    return dataclasses.replace(effect, edit=edit, truth=truth)


_WRAPPED = {"current_offset": _or_ripple, "dead_time": _or_drive_stage}
LIBRARY: tuple[Effect, ...] = (
    tuple(_WRAPPED[e.name](e) if e.name in _WRAPPED else e for e in EFFECTS) + RECORD_EFFECTS
)
BY_NAME = {e.name: e for e in LIBRARY}
