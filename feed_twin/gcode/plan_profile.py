# pyright: reportConstantRedefinition=false
# (G, J, A are the field's symbols for an integral, a jerk and an acceleration, not constants)
"""Planner stage 4, speed profile: boundary speeds of the bodies, then s(t) as pieces.

The bodies' boundary speeds come from a backward pass of braking bounds and a forward pass
(`profile.plan_speeds`), each body's peak speed and phase durations from `profile.body_profiles`.
The profile is a list of pieces, three per 1-D node: a hold (dwells, standstill), a cruise over
the node's blend at constant speed, and the body to the next 1-D node; a last hold at the end.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.items import Event, Stop
from feed_twin.gcode.jerk_filter import body_profiles_filtered, plan_speeds_filtered
from feed_twin.gcode.plan_chains import CHAIN_ENTRY, Bodies
from feed_twin.gcode.profile import BODY, CRUISE, HOLD, body_profiles, plan_speeds

PIECES_PER_NODE = 3  # hold, cruise, body
HOLD_SLOT, CRUISE_SLOT, BODY_SLOT = 0, 1, 2  # position of each within a node's three


@dataclass(frozen=True, kw_only=True)
class SpeedProfile:
    """Boundary speeds (m+1) and per-body peak speed and phase durations (m)."""

    v: np.ndarray  # [m/s] speed at each 1-D node
    vp: np.ndarray  # [m/s] peak speed of each body
    t_up: np.ndarray  # [s] speed-up phase
    t_cruise: np.ndarray  # [s] cruise at vp
    t_down: np.ndarray  # [s] slow-down phase
    A: np.ndarray  # [m/s^2] acceleration of each body's speed-up and slow-down


def speed_profile(bodies: Bodies, *, v_first: float, window_s: float = 0.0) -> SpeedProfile:
    """The fastest profile within the bodies' limits that starts at v_first and ends at rest.

    With a jerk filter window T (`window_s` > 0) it is the raw plan of `jerk_filter`:
    trapezoids, extended nodes, a cruise of T at every peak.
    """
    L, V, A = bodies.length, bodies.V, bodies.A
    if window_s > 0.0:
        v = plan_speeds_filtered(bodies.cap, L, A, bodies.hold_in, bodies.hold_out, v_first)
        vp, t_up, t_cruise, t_down, A = body_profiles_filtered(
            v, L, V, A, bodies.hold_in, bodies.hold_out, window_s
        )
    else:
        v = plan_speeds(bodies.cap, L, A, v_first)
        vp, t_up, t_cruise, t_down = body_profiles(v, L, V, A)
    return SpeedProfile(v=v, vp=vp, t_up=t_up, t_cruise=t_cruise, t_down=t_down, A=A)


FIT_SLACK = 1e-9  # relative: a speed or a braking distance this much over its bound fits


def speeds_fit(bodies: Bodies, v: np.ndarray) -> bool:
    """Whether boundary speeds v [m/s] keep within the 1-D nodes' caps and every body changes
    between its end speeds within its length, its nodes' holds included.

    The backward pass makes this so from any start its braking bounds allow; a window that goes
    on from committed motion starts at v_first, which only the committed window's constraints
    bounded: where this window's are tighter, the forward pass cannot keep them
    (`jerk_filter._braked_to`) and this is False."""
    v0, v1 = v[:-1], v[1:]
    change = np.abs(v0 * v0 - v1 * v1)
    with np.errstate(divide="ignore", invalid="ignore"):
        used = np.where(change > 0.0, change / (2.0 * bodies.A), 0.0)
    used += bodies.hold_out[:-1] * v0 + bodies.hold_in[1:] * v1
    within_caps = np.all(v[1:] <= bodies.cap[1:] * (1.0 + FIT_SLACK))
    return bool(within_caps and np.all(used <= bodies.length * (1.0 + FIT_SLACK) + 1e-15))


@dataclass(frozen=True, kw_only=True)
class Pieces:
    """The 1-D profile pieces in time order (arrays of one length; see `profile.sample_pieces`)."""

    key: np.ndarray  # sort key: PIECES_PER_NODE * slot + position; holds of dwells in between
    kind: np.ndarray  # BODY, CRUISE or HOLD
    dur: np.ndarray  # [s]
    s0: np.ndarray  # [m] path parameter at the start
    v0: np.ndarray  # [m/s] speed at the start
    vp: np.ndarray  # [m/s] peak speed (bodies)
    v1: np.ndarray  # [m/s] speed at the end (bodies)
    A: np.ndarray  # [m/s^2] acceleration limit (bodies; 1 elsewhere)
    t_up: np.ndarray  # [s] speed-up phase (bodies)
    t_cruise: np.ndarray  # [s] cruise phase (bodies)
    line: np.ndarray  # source line shown while the piece runs (-1: the move's own)
    seg: np.ndarray  # first move the piece runs on


def motion_pieces(
    bodies: Bodies,
    speeds: SpeedProfile,
    *,
    q_commit: int,
    n_moves: int,
) -> Pieces:
    """Hold, cruise and body pieces of the 1-D nodes before `q_commit`, and a last hold.

    A held node (jerk filter) cruises hold_in v before its blend and hold_out v after it
    (T v / 2 each at an extended node), where the bodies next to it start and end.
    """
    q = np.arange(q_commit)
    nodes = bodies.node[: q_commit + 1]
    v_node = speeds.v[: q_commit + 1]
    sa, sb = bodies.sa, bodies.sb
    n_pieces = PIECES_PER_NODE * q_commit + 1
    kind = np.full(n_pieces, HOLD, dtype=np.int64)
    dur = np.zeros(n_pieces)
    s0 = np.zeros(n_pieces)
    v0 = np.zeros(n_pieces)
    vpk = np.zeros(n_pieces)
    v1 = np.zeros(n_pieces)
    Ak = np.ones(n_pieces)
    tu = np.zeros(n_pieces)
    tc = np.zeros(n_pieces)
    # First move each piece runs on: a blend or a chain starts on the move before its node.
    before = np.maximum(nodes[:-1] - 1, 0)
    hold = PIECES_PER_NODE * q + HOLD_SLOT
    cruise = PIECES_PER_NODE * q + CRUISE_SLOT
    body = PIECES_PER_NODE * q + BODY_SLOT
    seg = np.zeros(n_pieces, dtype=np.int64)
    seg[hold] = before
    seg[cruise] = before
    kind_q = bodies.kind[:q_commit]
    seg[body] = np.where(kind_q == CHAIN_ENTRY, before, np.minimum(nodes[:-1], n_moves - 1))
    seg[-1] = n_moves - 1
    kind[cruise] = CRUISE
    reach_in = bodies.hold_in[: q_commit + 1] * v_node
    reach_out = bodies.hold_out[:q_commit] * v_node[:-1]
    span = sb[:q_commit] - sa[:q_commit] + reach_in[:-1] + reach_out
    with np.errstate(divide="ignore", invalid="ignore"):
        dur[cruise] = np.where(span > 0.0, span / v_node[:-1], 0.0)
    s0[cruise] = sa[:q_commit] - reach_in[:-1]
    v0[cruise] = v_node[:-1]
    s0[hold] = sa[:q_commit] - reach_in[:-1]
    kind[body] = BODY
    dur[body] = speeds.t_up[:q_commit] + speeds.t_cruise[:q_commit] + speeds.t_down[:q_commit]
    s0[body] = sb[:q_commit] + reach_out
    v0[body] = v_node[:-1]
    vpk[body] = speeds.vp[:q_commit]
    v1[body] = v_node[1:]
    Ak[body] = speeds.A[:q_commit]
    tu[body] = speeds.t_up[:q_commit]
    tc[body] = speeds.t_cruise[:q_commit]
    s0[-1] = sa[q_commit] - reach_in[-1]
    return Pieces(
        key=np.arange(n_pieces, dtype=float),
        kind=kind,
        dur=dur,
        s0=s0,
        v0=v0,
        vp=vpk,
        v1=v1,
        A=Ak,
        t_up=tu,
        t_cruise=tc,
        line=np.full(n_pieces, -1, dtype=np.int64),
        seg=seg,
    )


class Dwell(NamedTuple):
    """A hold piece for a dwell at a 1-D node."""

    key: float  # sort key: just before the node's hold slot (stop holds before dwells)
    dur: float  # [s]
    s: float  # [m] path parameter of the node
    line: int  # source line of the dwell
    node: int  # polyline node


class TimedEvent(NamedTuple):
    slot: int  # 1-D node the event belongs to
    offset: float  # [s] after the start of the node's dwells
    event: Event


def node_entries(
    slots: list[tuple[int, int, list[Event | Stop]]], S: np.ndarray
) -> tuple[list[Dwell], list[TimedEvent]]:
    """Dwells and events of the 1-D nodes: `slots` holds (slot, polyline node, entries)."""
    dwells: list[Dwell] = []
    timed: list[TimedEvent] = []
    for slot, node, entries in slots:
        offset = 0.0
        for i, entry in enumerate(entries):
            if isinstance(entry, Stop):
                key = PIECES_PER_NODE * slot - 0.5 + 0.5 * i / len(entries)
                dwells.append(Dwell(key, entry.dwell_s, S[node], entry.line, node))
                offset += entry.dwell_s
            else:
                timed.append(TimedEvent(slot, offset, entry))
    return dwells, timed


def stop_holds(
    bodies: Bodies,
    speeds: SpeedProfile,
    *,
    q_commit: int,
    final: bool,
    window_s: float,
    period: float,
) -> list[Dwell]:
    """Holds at each 1-D node where the raw plan stops, so that the filtered plan (window T,
    `jerk_filter`) comes to rest there too: T before the node's dwells and events, and one
    period after them, so that its arrival and its departure (along different moves) never
    share a sample. The program's end needs T alone.

    The window's first node is left out where the path was at rest before it (the start).
    """
    if window_s <= 0.0:
        return []
    last = q_commit + 1 if final else q_commit
    slots = np.flatnonzero(speeds.v[:last] == 0.0)
    holds: list[Dwell] = []
    for q in slots:
        if q == 0 and not (speeds.v[0] == 0.0 and bodies.node[0] > 0):
            continue
        s, node = float(bodies.sa[q]), int(bodies.node[q])
        holds.append(Dwell(PIECES_PER_NODE * int(q) - 0.9, window_s, s, -1, node))
        if not (final and q == q_commit):
            holds.append(Dwell(PIECES_PER_NODE * int(q) - 1e-6, period, s, -1, node))
    return holds


def with_dwells(pieces: Pieces, dwells: list[Dwell]) -> Pieces:
    """The pieces with a hold for each dwell, in time order."""
    if not dwells:
        return pieces
    extra_key = [d.key for d in dwells]
    extra_node = [d.node for d in dwells]
    zeros = np.zeros(len(extra_key))
    joined = Pieces(
        key=np.concatenate((pieces.key, extra_key)),
        kind=np.concatenate((pieces.kind, np.full(len(extra_key), HOLD))),
        dur=np.concatenate((pieces.dur, [d.dur for d in dwells])),
        s0=np.concatenate((pieces.s0, [d.s for d in dwells])),
        v0=np.concatenate((pieces.v0, zeros)),
        vp=np.concatenate((pieces.vp, zeros)),
        v1=np.concatenate((pieces.v1, zeros)),
        A=np.concatenate((pieces.A, zeros + 1.0)),
        t_up=np.concatenate((pieces.t_up, zeros)),
        t_cruise=np.concatenate((pieces.t_cruise, zeros)),
        line=np.concatenate((pieces.line, [d.line for d in dwells])),
        seg=np.concatenate((pieces.seg, np.maximum(np.array(extra_node) - 1, 0))),
    )
    order = np.argsort(joined.key, kind="stable")
    return replace(joined, **{f.name: getattr(joined, f.name)[order] for f in fields(Pieces)})
