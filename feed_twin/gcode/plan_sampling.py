"""Planner stage 5, sampling: the pieces' s(t) at t = k * period, mapped onto the blended path.

`profile.sample_pieces` gives s, ds/dt, d2s/dt2 at the sample times; `profile.evaluate_path`
turns them into axis position, velocity and acceleration on the polyline with its corner
blends (x'(s) s' and x'(s) s'' + x''(s) s'^2). Events get the time of their node: the start of
its dwells, or the middle of its blend.
"""

from __future__ import annotations

import math

import numpy as np

from feed_twin.gcode.jerk_filter import box_filter, raw_samples
from feed_twin.gcode.plan_limits import MoveLimits
from feed_twin.gcode.plan_profile import CRUISE_SLOT, HOLD_SLOT, PIECES_PER_NODE, Pieces, TimedEvent
from feed_twin.gcode.profile import evaluate_path, sample_pieces
from feed_twin.gcode.trajectory import NcEvent

END_SLACK = 1e-9  # [periods] a program's end this close past a sample time ends on that sample
WINDOW_SLACK = 1e-12  # [periods] the same for a window's end (the next window goes on)


def piece_starts(pieces: Pieces, t_s: float) -> tuple[np.ndarray, float]:
    """Start time of every piece and the end time [s], the first piece starting at t_s."""
    if not np.all(np.isfinite(pieces.dur)):
        raise RuntimeError("planner error: a corner blend planned at rest (please report)")
    t0 = t_s + np.concatenate(([0.0], np.cumsum(pieces.dur)[:-1]))
    t_end = t_s + float(np.sum(pieces.dur))
    return t0, t_end


def event_times(
    timed: list[TimedEvent], pieces: Pieces, t0: np.ndarray, t_end: float, q_commit: int
) -> list[NcEvent]:
    """Each event at its node's time: the start of its dwells, or the middle of its blend."""
    key, dur = pieces.key, pieces.dur
    events: list[NcEvent] = []
    for slot, offset, entry in timed:
        k_hold = int(np.searchsorted(key, PIECES_PER_NODE * slot + HOLD_SLOT - 0.5))
        start = t0[k_hold] if k_hold < len(t0) else t_end
        cruise_slot = int(np.searchsorted(key, PIECES_PER_NODE * slot + CRUISE_SLOT))
        if slot < q_commit and dur[cruise_slot] > 0.0:
            start = t0[cruise_slot] + 0.5 * dur[cruise_slot]
        events.append(
            NcEvent(float(start + offset), entry.line, entry.kind, entry.value, entry.text)
        )
    return events


def sample_indices(k_next: int, t_end: float, period: float, *, final: bool) -> tuple[int, int]:
    """Sample indices [k_next, k_stop) up to t_end; the last one at or after a program's end."""
    if final:
        return k_next, math.ceil(t_end / period - END_SLACK) + 1
    return k_next, max(math.ceil(t_end / period - WINDOW_SLACK), k_next)


def _on_path(
    s: np.ndarray,
    sd: np.ndarray,
    sdd: np.ndarray,
    *,
    S: np.ndarray,
    moves: MoveLimits,
    w: np.ndarray,
    dU: np.ndarray,
    move: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Path length s, ds/dt and d2s/dt2 mapped onto the blended path from each sample's first
    move (`evaluate_path`): position, velocity, acceleration and the move each is on."""
    n = len(moves.L)
    return evaluate_path(
        s,
        sd,
        sdd,
        S[:-1],
        moves.L,
        moves.P[:-1],
        moves.P[1:],
        moves.u,
        w[:n],
        dU[:n],
        w[1:],
        dU[1:],
        move,
    )


def sample_path(
    times: np.ndarray,
    pieces: Pieces,
    t0: np.ndarray,
    moves: MoveLimits,
    w: np.ndarray,
    dU: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(position, velocity, acceleration, piece, move) at each sample time."""
    S = np.concatenate(([0.0], np.cumsum(moves.L)))
    s, sd, sdd, piece = sample_pieces(
        times,
        pieces.kind,
        t0,
        pieces.dur,
        pieces.s0,
        pieces.v0,
        pieces.vp,
        pieces.v1,
        pieces.A,
        pieces.t_up,
        pieces.t_cruise,
    )
    pos, vel, acc, seg = _on_path(s, sd, sdd, S=S, moves=moves, w=w, dU=dU, move=pieces.seg[piece])
    return pos, vel, acc, piece, seg


def sample_filtered(
    times: np.ndarray,
    pieces: Pieces,
    t0: np.ndarray,
    moves: MoveLimits,
    w: np.ndarray,
    dU: np.ndarray,
    *,
    history: np.ndarray,
    F0: tuple[float, float],
    span: float,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[float, float]
]:
    """(position, velocity, acceleration, piece, move, history, F_end) with the jerk filter.

    The raw plan's s, ds/dt and F (the integral of s, F0 at the first piece's start, as the
    sum of two doubles: `jerk_filter.raw_samples`) at the sample times follow the `history`
    rows (`jerk_filter.ROW_*` of the samples within `span` before them);
    `jerk_filter.box_filter` averages them and the result is mapped onto the path. Returned:
    the new history and F at the end of the pieces.
    """
    n = len(moves.L)
    S = np.concatenate(([0.0], np.cumsum(moves.L)))
    p = pieces
    s, sd, F, F_lo, piece, F_end, F_end_lo = raw_samples(
        times, p.kind, t0, p.dur, p.s0, p.v0, p.vp, p.A, p.t_up, p.t_cruise, F0[0], F0[1]
    )
    raw = np.column_stack((s, sd, F, times, F_lo))
    smooth = box_filter(history, raw, span)
    # At a node itself a sample belongs to the move it leaves on once the raw plan is past it
    # (arriving at a stop, the raw plan is at the node: the move it arrives on).
    moving = s > smooth[:, 0]
    first = np.where(
        moving, np.searchsorted(S, smooth[:, 0], "right"), np.searchsorted(S, smooth[:, 0])
    )
    pos, vel, acc, seg = _on_path(
        smooth[:, 0],
        smooth[:, 1],
        smooth[:, 2],
        S=S,
        moves=moves,
        w=w,
        dU=dU,
        move=np.clip(first - 1, 0, n - 1),
    )
    joined = np.concatenate((history, raw))
    return pos, vel, acc, piece, seg, joined[len(raw) :], (float(F_end), float(F_end_lo))
