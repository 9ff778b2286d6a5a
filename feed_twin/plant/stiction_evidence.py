"""Where a record shows a table held still by friction (`held_stops`), and how much of its
sliding force the drive holds there as the table comes to rest (`held_share`): the evidence
the stiction effect of plant.stiction_friction is ranked on, and chooses its contact by.
"""

from __future__ import annotations

import numpy as np

from feed_twin.core.arrays import FloatArray
from feed_twin.plant.effect_api import MOVING_SPEEDS, Motion

# a table that stands still this long is held there by friction: a sliding friction lets the
# loop creep it onto its target (the truth machine's atan law at 2e-5 m/s, as sharp as a real
# guide's, stood 24-42 ms at its longest on records without stiction; held, 171-287 ms)
HOLD_MIN_S = 0.1
# the still band: this many of the position's steps at rest (its quantum, or its noise)
HOLD_BAND_STEPS = 2.5
# the force held over a still span, as an RMS over it, against the effort's sample noise: a
# noise alone is 1, the nominal twin's own settling in it up to about 2.5
HOLD_FORCE_NOISE = 4.0
POSITION_ZERO_M = 1e-12  # steps below this are the record's decimal rounding, not a move
# the first part of a held stop, where the force the table was caught with is held before the
# loop's integrator winds it on
CATCH_SHARE = 0.25


def held_share(m: Motion, spans: list[tuple[int, int]]) -> float | None:
    """The share of its sliding force the drive holds as its table comes to rest: over the
    first CATCH_SHARE of each held stop (one sample at least), the effort less its constant
    part, in the direction the table came from (its speed over the HOLD_MIN_S before), over
    the record's Coulomb force (a least-squares split of the moving samples' effort into a
    constant, sign(v), v and a); the median over the stops. None where the record has no
    effort or shows no sliding force."""
    e = m.effort_meas
    if e is None:
        return None
    v, t = m.v_m_s, m.t_s
    is_moving = np.abs(v) > MOVING_SPEEDS * m.speed_eps
    split = np.column_stack([np.ones(len(v)), np.sign(v), v, m.a_m_s2])[is_moving]
    if len(split) <= split.shape[1]:
        return None
    constant, coulomb, _, _ = np.linalg.lstsq(split, e[is_moving], rcond=None)[0]
    if not coulomb > 0.0:
        return None
    shares: list[float] = []
    for a, b in spans:
        came = float(np.sign(np.sum(v[np.searchsorted(t, t[a] - HOLD_MIN_S) : a])))
        caught = slice(a, a + max(1, int(CATCH_SHARE * (b - a))))
        if came != 0.0:
            shares.append(came * (float(np.mean(e[caught])) - constant) / coulomb)
    return float(np.median(shares)) if shares else None


def held_stops(m: Motion) -> list[tuple[int, int]]:
    """(first, end) of each span after the first move over which the table stays within
    HOLD_BAND_STEPS of the position's steps at rest from where it stopped, for HOLD_MIN_S at
    least, holding a force (`_holding`)."""
    x, t = m.x_m, m.t_s
    slow = np.abs(m.v_m_s) <= MOVING_SPEEDS * m.speed_eps
    if slow.all() or not slow.any():
        return []
    band = HOLD_BAND_STEPS * _position_step(x, slow)
    starts = np.flatnonzero(slow)
    spans: list[tuple[int, int]] = []
    a = int(np.argmax(~slow))  # after the first move: the contact's state is known
    while (nxt := np.searchsorted(starts, a)) < len(starts):
        a = int(starts[nxt])
        b = _still_until(x, a, band)
        if t[b - 1] - t[a] >= HOLD_MIN_S and _holding(m, slice(a, b)):
            spans.append((a, b))
        a = b
    return spans


def _holding(m: Motion, span: slice) -> bool:
    """Over a span where the table stands still, the drive holds a force the nominal twin does
    not: the effort residual's RMS there is HOLD_FORCE_NOISE times the effort's sample noise
    (true where the record has no effort: the position alone is the evidence then). A table
    resting in a backlash gap stands still as long (the truth machine's: 180-260 ms, 8 um off
    its command) with nothing pushing it (residual 1.0-2.4x the noise; held by stiction,
    8.8-10x)."""
    if m.effort_meas is None or m.effort_sim is None:
        return True
    e = m.effort_meas[span]
    held = float(np.sqrt(np.mean((e - m.effort_sim[span]) ** 2)))
    noise = 1.4826 * float(np.median(np.abs(np.diff(e)))) / np.sqrt(2.0)
    return held > HOLD_FORCE_NOISE * noise


def _position_step(x: FloatArray, slow: np.ndarray) -> float:
    """The smallest change the position record shows: its quantum (the smallest step between
    samples), or its sample noise at low speed where that is larger (white noise of standard
    deviation sigma has second differences of sigma sqrt(6))."""
    steps = np.abs(np.diff(x))
    moved = steps[steps > POSITION_ZERO_M]
    quantum = float(np.min(moved)) if len(moved) else 0.0
    curvature = np.abs(np.diff(x, 2))[slow[1:-1]]
    noise = 1.4826 * float(np.median(curvature)) / np.sqrt(6.0) if len(curvature) else 0.0
    return max(quantum, noise)


def _still_until(x: FloatArray, a: int, band: float) -> int:
    """The first sample after `a` that lies more than `band` from x[a] (len(x) if none)."""
    width = 64
    while True:
        off = np.flatnonzero(np.abs(x[a : a + width] - x[a]) > band)
        if len(off):
            return a + int(off[0])
        if a + width >= len(x):
            return len(x)
        width *= 2
