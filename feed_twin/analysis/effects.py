"""The library of effects a twin may miss: the plant's declared effects plus the record's own.

Each effect is declared by the plant component that carries it (feed_twin.plant.effect_api.
Effect in the component's `EFFECTS`, collected by feed_twin.plant.registry): its signature (a
small set of regressors, functions of the measured motion, that the residual it causes would
follow; feed_twin.analysis.ranking projects residuals onto them and tests them), the edit of
the component's own parameters and the synthetic truth. This module adds the one effect that is
no part of the machine but of the record (channel_delay) and orders the library.

Domains: force-like effects act on the drive effort; position-like effects (sensor delay, lead
error, backlash with a linear scale, thermal growth) act on the measured position. The
inverter's dead time acts on the voltage: it is ranked on the q-axis voltage the current
controller commands, when the record has it, and falls back to the effort otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping

from feed_twin.analysis.model_doc import EFFORT_DELAY_SLOT
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


def _channel_delay_edit(doc: Document, cand: Weights) -> Edit:
    """The record's effort is stamped later than its position (or earlier): not a change of
    the machine, a shift of the twin's effort before it is compared (analysis.twin.delayed),
    searched over a grid and kept in the model's `analysis` section."""
    del cand
    period = doc.base_period()
    grid = tuple(
        0.5 * period * k for k in range(-2 * CHANNEL_DELAY_PERIODS, 2 * CHANNEL_DELAY_PERIODS + 1)
    )
    doc = doc.set(EFFORT_DELAY_SLOT, doc.get(EFFORT_DELAY_SLOT))
    own = [FreeParameter(name=EFFORT_DELAY_SLOT, initial=0.0, scale=period)]
    report = {"delay_s": lambda v: v[EFFORT_DELAY_SLOT]}
    return make_edit(doc, own, report, interacts=False, grid=grid)


def _channel_delay_truth(doc: Document, p: Mapping[str, float]) -> Document:
    return doc.set(EFFORT_DELAY_SLOT, p["delay_s"])


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
        truth=_channel_delay_truth,
    ),
)
LIBRARY: tuple[Effect, ...] = EFFECTS + RECORD_EFFECTS
BY_NAME = {e.name: e for e in LIBRARY}
