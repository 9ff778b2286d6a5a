"""Planner stage 3, chains: the 1-D nodes of the speed profile and the bodies between them.

Neighbouring corners whose blends meet leave no straight piece between them: they form a
chain, which the speed profile treats as one body (or a few, cut where its local speed cap
changes by more than CHAIN_CUT) with the axis limits shared between the curvature terms and
s'' and s''' (`chain_limits`). A corner blended alone is a 1-D node crossed at constant speed
over its blend. Collinear joints with equal limits are passed through.

With the jerk filter (`jerk_filter`) a chain is cut at every node, so its speed cap follows
the curvature node by node (the raw plan needs no room for an S-curve per body); the caps
and acceleration limits of its bodies are eroded over the distance a filter window spans,
and stops, sharp corners and passing points are extended (speed held T v / 2 beyond the blend).
A chain's end next to a straight move whose far end is held is held T on the straight side
(`_held_chain_ends`), so that move is planned with its own limits, not the chain's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.jerk_filter import erode
from feed_twin.gcode.plan_blends import CHAIN_SHARE, SHARP_CORNER, CornerBlends, NodeFlags
from feed_twin.gcode.plan_limits import AxisLimits, MoveLimits

CHAIN_CUT = 1.3  # a chain is cut where its local speed cap changes by more than this factor
# With the jerk filter: the share of each axis's jerk the curvature's own change (x''' v^3)
# may take at a chain's speed cap; s''' and the cross term share the rest through A.
# A higher share lifts the cap and leaves less to A: over the peer corpus 0.6-0.65 gave the
# shortest times of 0.4-0.85 (0.75 before: cam_trochoidal_pocket 9.913 -> 9.786 s,
# incremental 3.639 -> 3.553 s; dense_segments and inch about 0.4 % slower).
CURVE_JERK_SHARE = 0.65
# The trapezoid's share of each axis's acceleration for the curvature (x'' v^2) at a chain's
# speed cap (half before); s'' takes what it leaves. The filtered plan keeps half: its s''
# feeds the jerk too.
CURVE_ACC_SHARE = 0.75
SAME_CAP = 0.01  # neighbouring moves whose speed caps differ by less than this share: one cap

# Kinds of 1-D node
SINGLE = 0  # a corner blended alone (or a stop, or a passing point): cruise over its blend
CHAIN_ENTRY = 1  # where a chain starts: the body after it runs along the chain
CHAIN_EXIT = 2  # where a chain ends
CHAIN_CUT_NODE = 3  # a cut inside a chain: bodies of the chain on both sides


class ChainTerms(NamedTuple):
    """Per body (m, n_axes), the largest over the blends it meets of |d_i''| (a_g [1/m]),
    |d_i'''| (j_g [1/m^2]), the curvature steps (k_g [1/m]) and |d_i| (u_g)."""

    a_g: np.ndarray
    j_g: np.ndarray
    k_g: np.ndarray
    u_g: np.ndarray


class ChainRelax(NamedTuple):
    """What the chain bodies' acceleration limits come from (`plan_relax`): their curvature
    terms, the chain each is eroded within (-1: none) and where each lies along s [m]."""

    terms: ChainTerms
    V: np.ndarray  # [m/s] the speed cap of each body before erosion (chain_limits)
    node_cap: np.ndarray  # [m/s] the speed cap of each 1-D node's blend (m+1)
    group: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


@dataclass(frozen=True, kw_only=True)
class Bodies:
    """1-D nodes q (arrays of m+1) and the bodies between consecutive ones (arrays of m)."""

    node: np.ndarray  # (m+1,) polyline node of each 1-D node
    kind: np.ndarray  # (m+1,) SINGLE, CHAIN_ENTRY, CHAIN_EXIT or CHAIN_CUT_NODE
    S: np.ndarray  # (n+1,) [m] path parameter of every polyline node
    sa: np.ndarray  # (m+1,) [m] where the 1-D node's blend starts (s)
    sb: np.ndarray  # (m+1,) [m] where it ends and the next body starts
    cap: np.ndarray  # (m+1,) [m/s] speed cap at the 1-D node
    length: np.ndarray  # (m,) [m] body lengths
    V: np.ndarray  # (m,) [m/s] speed cap of each body
    A: np.ndarray  # (m,) [m/s^2] acceleration limit of s'' on each body
    J: np.ndarray  # (m,) [m/s^3] jerk limit of s''' on each body
    extended: np.ndarray  # (m+1,) the raw plan holds the node's speed T v / 2 beyond its blend
    hold_in: np.ndarray  # (m+1,) [s] the raw plan holds the node's speed v this long before it
    hold_out: np.ndarray  # (m+1,) [s] and this long after it (T / 2 each where extended)
    relax: ChainRelax | None = None  # what `plan_relax` needs to raise the chains' A (filtered)


class StartHolds(NamedTuple):
    """The holds of a window's first 1-D node, as the window that committed it planned them."""

    extended: bool
    hold_in: float  # [s]
    hold_out: float  # [s]


def chain_bodies(
    moves: MoveLimits,
    blends: CornerBlends,
    flags: NodeFlags,
    limits: AxisLimits,
    *,
    first: int,
    open_end: bool,
    holds_as: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    start_holds: StartHolds | None = None,
) -> Bodies | None:
    """Group the nodes from `first` on into 1-D nodes and bodies; None if fewer than two.

    With `open_end` the window's last body stops short of the last move, where the next
    window may put a blend: every speed planned now stays reachable later. `holds_as` gives
    the extended 1-D nodes and the holds (of the same 1-D nodes) instead of choosing them.
    `start_holds` fixes those of the first 1-D node: a window that goes on from a committed
    one keeps the holds the committed raw plan already ran (it ended hold_in v before the
    node), so that s goes on where it stopped.
    """
    L, V, A, J = moves.L, moves.V, moves.A, moves.J
    n = len(L)
    w = blends.w
    same_limits = np.zeros(n + 1, dtype=bool)
    same_limits[1:n] = (V[:-1] == V[1:]) & (A[:-1] == A[1:]) & (J[:-1] == J[1:])
    passing = ~blends.corner & same_limits & ~(blends.stop | flags.has_entries | flags.forced)
    passing &= ~(w > 0.0)
    passing[: first + 1] = False
    nodes_b = np.flatnonzero(~passing)
    nodes_b = nodes_b[nodes_b >= first]
    pos_q, kind_q = _one_d_nodes(nodes_b, L, blends, limits)
    node_q = nodes_b[pos_q]
    S = np.concatenate(([0.0], np.cumsum(L)))
    sa = np.where(kind_q == SINGLE, S[node_q] - w[node_q], S[node_q])
    sa = np.where(kind_q == CHAIN_ENTRY, S[node_q] - w[node_q], sa)
    sa = np.where(kind_q == CHAIN_EXIT, S[node_q] + w[node_q], sa)
    sb = np.where(kind_q == SINGLE, S[node_q] + w[node_q], sa)
    if len(node_q) < 2:
        return None
    length = np.maximum(sa[1:] - sb[:-1], 0.0)
    if open_end:
        length[-1] = max(length[-1] - CHAIN_SHARE * L[n - 1], 0.0)
    filtered = limits.window_s > 0.0
    T = limits.window_s
    extended = np.zeros(len(kind_q), dtype=bool)
    hold_in = np.zeros(len(kind_q))
    hold_out = np.zeros(len(kind_q))
    if holds_as is not None:
        extended, hold_in, hold_out = holds_as
    elif filtered:
        extended = _extended(kind_q, node_q, blends, V, length, T)
        if start_holds is not None:
            extended[0] = start_holds.extended
        end_in, end_out = _held_chain_ends(kind_q, blends.cap[node_q], length, extended, T)
        hold_in = np.where(extended, 0.5 * T, np.where(end_in, T, 0.0))
        hold_out = np.where(extended, 0.5 * T, np.where(end_out, T, 0.0))
        if start_holds is not None:
            hold_in[0], hold_out[0] = start_holds.hold_in, start_holds.hold_out
    if filtered:
        # Bodies a filter window may share with a neighbour: planned as chains, eroded.
        in_chain = ~((hold_out[:-1] > 0.0) & (hold_in[1:] > 0.0))
    else:
        in_chain = (kind_q[:-1] == CHAIN_ENTRY) | (kind_q[:-1] == CHAIN_CUT_NODE)
    quiet = np.zeros(len(nodes_b), dtype=bool)
    quiet[pos_q] = extended
    Vc, Ac, Jc, terms = chain_limits(
        nodes_b, pos_q, blends, u=moves.u, V=V, limits=limits, quiet=quiet
    )
    relax = None
    if filtered:
        group = erosion_groups(in_chain, hold_out[:-1] > 0.0)
        Vc_local = Vc
        Vc, Ac = _eroded(sb[:-1], sa[1:], Vc, Ac, group=group, T=T)
        relax = ChainRelax(
            terms=terms, V=Vc_local, node_cap=blends.cap[node_q], group=group, lo=sb[:-1], hi=sa[1:]
        )
    cap = blends.cap
    cap_q = cap[node_q].copy()
    cap_q[1:] = np.where(in_chain, np.minimum(cap_q[1:], Vc), cap_q[1:])
    cap_q[:-1] = np.where(in_chain, np.minimum(cap_q[:-1], Vc), cap_q[:-1])
    if not filtered:
        cap_q = np.where(kind_q == SINGLE, cap[node_q], cap_q)
    pairs = np.column_stack((node_q[:-1], node_q[1:])).ravel()
    pad = np.array([np.inf])
    Vb = np.minimum.reduceat(np.concatenate((V, pad)), pairs)[::2]
    Ab = np.minimum.reduceat(np.concatenate((A, pad)), pairs)[::2]
    Jb = np.minimum.reduceat(np.concatenate((J, pad)), pairs)[::2]
    return Bodies(
        node=node_q,
        kind=kind_q,
        S=S,
        sa=sa,
        sb=sb,
        cap=cap_q,
        length=length,
        V=np.where(in_chain, Vc, Vb),
        A=np.where(in_chain, Ac, Ab),
        J=np.where(in_chain, Jc, Jb),
        extended=extended,
        hold_in=hold_in,
        hold_out=hold_out,
        relax=relax,
    )


def _extended(
    kind_q: np.ndarray,
    node_q: np.ndarray,
    blends: CornerBlends,
    V: np.ndarray,
    length: np.ndarray,
    T: float,
) -> np.ndarray:
    """1-D nodes whose speed the filtered raw plan holds T v / 2 beyond the blend
    (`jerk_filter`): stops; sharp corners and passing points where the speed cap changes,
    where the bodies on both sides leave any room; gentle corners where they leave room at
    the corner's cap. Not a chain's nodes, nor passing points between moves of (nearly) the
    same cap, nor gentle corners between short bodies: their neighbours' limits are eroded."""
    gentle = blends.corner & (np.sqrt(np.einsum("ij,ij->i", blends.dU, blends.dU)) <= SHARP_CORNER)
    V_in = np.concatenate(([np.inf], V))
    V_out = np.concatenate((V, [np.inf]))
    with np.errstate(invalid="ignore"):
        same_cap = np.abs(V_in - V_out) <= SAME_CAP * np.minimum(V_in, V_out)
    smooth = (gentle | (~blends.corner & same_cap)) & ~blends.stop
    room = np.minimum(np.concatenate(([np.inf], length)), np.concatenate((length, [np.inf])))
    wide = room >= 0.5 * T * blends.cap[node_q]
    single = kind_q == SINGLE
    return single & (
        blends.stop[node_q]
        | np.where(smooth[node_q] & gentle[node_q], wide, ~smooth[node_q] & (room > 0.0))
    )


def _held_chain_ends(
    kind_q: np.ndarray,
    cap: np.ndarray,
    length: np.ndarray,
    extended: np.ndarray,
    T: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Chain entries held T before their blend and chain exits held T after it: where the
    body on that side is a straight move whose other end is held too (an extended node, or
    the other chain's end), with room for both holds at the node's cap (2 T cap).

    Such a body is alone in every filter window (not a chain body): it runs at its move's
    limits and brakes to the chain's speed before the hold, where otherwise the whole move
    would take the chain's (eroded) speed cap. The hold is T, not T / 2: a window never
    spans both the body's braking and the chain (whose s'' may have either sign), so the
    filtered jerk stays within what each side budgets; the chain side needs no hold, its caps
    and accelerations are eroded within the chain."""
    m = len(length)
    room_before = np.concatenate(([0.0], length))
    room_after = np.concatenate((length, [0.0]))
    entry = (kind_q == CHAIN_ENTRY) & (room_before >= 2.0 * T * cap)
    exit_ = (kind_q == CHAIN_EXIT) & (room_after >= 2.0 * T * cap)
    held_before = np.concatenate(([False], extended[:m] | exit_[:m]))
    held_after = np.concatenate((extended[1:] | entry[1:], [False]))
    return entry & held_before, exit_ & held_after


def erosion_groups(in_chain: np.ndarray, after_extended: np.ndarray) -> np.ndarray:
    """The chain (0, 1, ...) each body's limits are eroded within, -1 for bodies alone in
    their windows: an extended node between two chain bodies parts them."""
    starts = (np.concatenate(([True], ~in_chain[:-1])) | after_extended) & in_chain
    return np.where(in_chain, np.cumsum(starts) - 1, -1)


def _eroded(
    lo: np.ndarray, hi: np.ndarray, V: np.ndarray, A: np.ndarray, *, group: np.ndarray, T: float
) -> tuple[np.ndarray, np.ndarray]:
    """Speed caps and acceleration limits of chain bodies (s from lo to hi) eroded within their
    chain (`group`): a filtered speed at s averages raw speeds within T v / 2 of s, a filtered
    acceleration raw ones within the distance the raw plan covers in T, at most T times the
    highest speed cap of the bodies between (`jerk_filter`)."""
    if not np.any(group >= 0):
        return V, A
    V_far = np.where(np.isfinite(V), V, 0.0)
    none = np.zeros(len(V))
    return (
        erode(lo, hi, V, 0.5 * T * V_far, group, none, 0.0),
        erode(lo, hi, A, none, group, V_far, T),
    )


def _one_d_nodes(
    nodes_b: np.ndarray, L: np.ndarray, blends: CornerBlends, limits: AxisLimits
) -> tuple[np.ndarray, np.ndarray]:
    """Positions within `nodes_b` of the 1-D nodes, and their kinds."""
    n = len(L)
    w = blends.w
    alone = blends.alone
    linked = (
        (w[nodes_b[:-1]] > 0.0)
        & (w[nodes_b[1:]] > 0.0)
        & (nodes_b[1:] == nodes_b[:-1] + 1)
        & (w[nodes_b[:-1]] + w[nodes_b[1:]] >= L[np.minimum(nodes_b[:-1], n - 1)])
        & ~alone[nodes_b[:-1]]
        & ~alone[nodes_b[1:]]
    )
    g_start = np.flatnonzero(np.concatenate(([True], ~linked)))
    g_end = np.flatnonzero(np.concatenate((~linked, [True])))
    in_group = np.arange(len(nodes_b))
    first_of = np.repeat(g_start, g_end - g_start + 1)
    last_of = np.repeat(g_end, g_end - g_start + 1)
    chained = last_of > first_of
    # A chain is cut where its local speed cap changes a lot (typically where the
    # curvature ramps up at its ends), so that a slow end does not slow all of it.
    local = limits.cruise_cap(
        blends.a_node[nodes_b], blends.j_node[nodes_b], 0.5, 1.0 / 3.0, blends.k_node[nodes_b]
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = local[1:] / local[:-1]  # inf/inf (straight stretches) gives nan: no cut
    cut = np.zeros(len(nodes_b), dtype=bool)
    cut[1:] = (ratio > CHAIN_CUT) | (ratio < 1.0 / CHAIN_CUT) | (limits.window_s > 0.0)
    cut &= chained & (in_group > first_of) & (in_group < last_of)
    emit = ~chained | (in_group == first_of) | (in_group == last_of) | cut
    pos_q = np.flatnonzero(emit)
    kind_q = np.where(
        ~chained[pos_q],
        SINGLE,
        np.where(
            in_group[pos_q] == first_of[pos_q],
            CHAIN_ENTRY,
            np.where(in_group[pos_q] == last_of[pos_q], CHAIN_EXIT, CHAIN_CUT_NODE),
        ),
    )
    return pos_q, kind_q


def chain_limits(
    nodes_b: np.ndarray,
    pos_q: np.ndarray,
    blends: CornerBlends,
    *,
    u: np.ndarray,
    V: np.ndarray,
    limits: AxisLimits,
    quiet: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, ChainTerms]:
    """Speed cap, acceleration and jerk [SI] of the body from each 1-D node to the next,
    as if it ran along a chain of overlapping blends (used where it does); the blends of
    `quiet` nodes (of `nodes_b`) are left out.

    Along a chain the axis motion is d(s) ds/dt with d a convex combination of the move
    directions (|d_i| <= max |u_i|), and
        a_i = d_i s'' + d'_i (s')^2,   j_i = d_i s''' + 3 d'_i s' s'' + d''_i (s')^3.
    The curvature terms take a share of each axis's acceleration and jerk at the cap V
    (trapezoid: CURVE_ACC_SHARE, no jerk; filtered: half and CURVE_JERK_SHARE, curvature
    steps included), s'' the acceleration they leave (A); filtered, s''' <= 2 A / T and the
    cross term share the jerk they leave. No jerk limit J of s''' itself (inf). The body
    from node p to node q meets the blends of nodes p..q, hence the maxima over them; those
    maxima (`ChainTerms`) are returned too.
    """
    absu = np.abs(u)
    zero = np.zeros((1, absu.shape[1]))
    u_node = np.maximum(np.vstack((zero, absu)), np.vstack((absu, zero)))
    v_node = np.minimum(np.concatenate(([np.inf], V)), np.concatenate((V, [np.inf])))
    u_node[nodes_b[quiet]] = 0.0
    v_node[nodes_b[quiet]] = np.inf
    pairs = np.column_stack((pos_q[:-1], pos_q[1:] + 1)).ravel()

    def over_bodies(values: np.ndarray, reduce: np.ufunc) -> np.ndarray:
        padded = np.concatenate((values[nodes_b], values[nodes_b][-1:]))
        return reduce.reduceat(padded, pairs, axis=0)[::2]

    seen = ~quiet[:, None]
    a_node = np.zeros_like(blends.a_node)
    j_node = np.zeros_like(blends.j_node)
    k_node = np.zeros_like(blends.k_node)
    a_node[nodes_b] = np.where(seen, blends.a_node[nodes_b], 0.0)
    j_node[nodes_b] = np.where(seen, blends.j_node[nodes_b], 0.0)
    k_node[nodes_b] = np.where(seen, blends.k_node[nodes_b], 0.0)
    a_g = over_bodies(a_node, np.maximum)
    j_g = over_bodies(j_node, np.maximum)
    k_g = over_bodies(k_node, np.maximum)
    u_g = over_bodies(u_node, np.maximum)
    filtered = limits.window_s > 0.0
    a_share, j_share = (0.5, CURVE_JERK_SHARE) if filtered else (CURVE_ACC_SHARE, 1.0)
    local = limits.cruise_cap(a_g, j_g, a_share, j_share, k_g)
    Vc = np.minimum(over_bodies(v_node, np.minimum), local)
    terms = ChainTerms(a_g=a_g, j_g=j_g, k_g=k_g, u_g=u_g)
    return Vc, chain_acceleration(terms, Vc, limits), np.full(len(Vc), np.inf), terms


def chain_acceleration(
    terms: ChainTerms, v: np.ndarray, limits: AxisLimits, *, one_sign: np.ndarray | None = None
) -> np.ndarray:
    """[m/s^2] The acceleration A of s'' that each body's curvature terms leave at speed v:
    d_i s'' + d'_i v^2 within a_max_i; filtered, d_i s''' + 3 d'_i v A + d''_i v^3 + the
    curvature steps' sampled jerk within j_max_i, with |s'''| <= 2 A / T (the raw s'' may
    change sign within a window), or A / T where `one_sign` says it does not (`plan_relax`)."""
    a_g, j_g, k_g, u_g = terms
    a_max, j_max = limits.a_max, limits.j_max
    vv = v[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        a_left = (a_max - a_g * vv * vv) / u_g
        if limits.window_s > 0.0:
            turns = 2.0 if one_sign is None else np.where(one_sign, 1.0, 2.0)[:, None]
            curve = j_g * vv**3 + limits.kick_jerk(k_g) * vv * vv
            j_left = (j_max - curve) / (turns * u_g / limits.window_s + 3.0 * a_g * vv)
            a_left = np.minimum(a_left, j_left)
        return np.min(np.where(u_g > 0.0, a_left, np.inf), axis=1)
