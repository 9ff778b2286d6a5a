"""Planner stage 2, corner blends: where the path rounds a corner (G64), how wide, how fast.

A corner between moves with directions u_in, u_out (dU = u_out - u_in) is blended over a
half-width w <= 6*tol/|dU|, so that the path stays within tol of the corner (deviation
|dU| w/6, see `profile`), and within a share of the neighbouring moves:
- a corner blended alone (sharp: |dU| > SHARP_CORNER, or with an event, or a forced break)
  takes at most BLEND_SHARE of each move, and its neighbours keep off (NEIGHBOUR_SHARE);
- gentle corners (chords of an arc, CAM polylines) may take whole moves (CHAIN_SHARE), so
  that neighbouring blends overlap into chains (next stage) with a continuous curvature.
A corner is crossed at a speed whose curvature terms dU_i h' v^2 and dU_i h'' v^3 stay within
every axis's a_max and j_max. Every corner is rounded: the path stops only where the program
says so (`NodeFlags.stop`). Nodes: node j is the start of move j (0..n).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.plan_limits import AxisLimits, MoveLimits

BLEND_SHARE = 0.4  # largest part of a move a corner blended alone may use
NEIGHBOUR_SHARE = 0.55  # the same for its neighbours, so that a straight piece stays between
# (with the jerk filter the straight piece holds the corner's speed T v / 2 beyond its blend;
# 0.3 kept more room for that on short CAM moves, but squeezed the neighbouring blend, whose
# curvature ramp then capped a whole chord chain: since a hold may take all of a body whose
# other end holds nothing (`jerk_filter.plan_speeds_filtered`), 0.55 is quicker on every
# corpus program, e.g. cam_surface_raster 27.942 -> 27.053 s, incremental 3.553 -> 3.476 s)
CHAIN_SHARE = 1.0  # elsewhere: blends may reach the neighbouring corner and overlap
SHARP_CORNER = 0.25  # |u_out - u_in| above this (about 14 degrees) is a corner, not a curve
COLLINEAR = 1e-12  # |u_out - u_in| below this is a straight joint, not a corner
ZONE_SLACK = 1e-9  # share of a move below which a blend zone on it is a rounding error
# With the jerk filter: a zone of one blend alone shorter than this share of its move (where
# neighbouring chords differ a little) is a step of curvature, not a slope (`zone_coefficients`)
KICK_ZONE = 0.1
# A corner blended alone is narrowed to the width its planned speed needs (`fitted_widths`)
# where that is below this share of its width, with the speed raised by WIDTH_MARGIN (rounding).
NARROWER = 0.9
WIDTH_MARGIN = 1e-6


@dataclass(frozen=True, kw_only=True)
class NodeFlags:
    """What the listed program says about each node (arrays of n+1)."""

    tol: np.ndarray  # [m] allowed deviation at the node (G64 P of the move ending there)
    stop: np.ndarray  # the path is at rest there (G61, G9, dwells, stopping M-codes, ends)
    has_entries: np.ndarray  # events or dwells happen there
    forced: np.ndarray  # a forced break of chains (bounds the look-ahead's work)


@dataclass(frozen=True, kw_only=True)
class CornerBlends:
    """Blends at the nodes (arrays of n+1; (n+1, n_axes) for vectors)."""

    corner: np.ndarray  # the direction changes there
    stop: np.ndarray  # at rest there (as the program says)
    alone: np.ndarray  # blended alone: not part of a chain
    w: np.ndarray  # [m] blend half-width (0: no blend)
    dU: np.ndarray  # direction change where blended, else 0
    cap: np.ndarray  # [m/s] speed cap of the corner (0 at stops)
    a_node: np.ndarray  # (n+1, n_axes) [1/m] largest |d2x/ds2| per axis around the node
    j_node: np.ndarray  # (n+1, n_axes) [1/m^2] largest |d3x/ds3| per axis around the node
    k_node: np.ndarray  # (n+1, n_axes) [1/m] largest curvature step per axis around the node


@dataclass(frozen=True, kw_only=True)
class WindowStart:
    """The committed context of a window that continues committed motion (decided earlier)."""

    w: np.ndarray  # [m] blend half-widths of the listed nodes up to the first uncommitted one
    stop: bool  # whether the path stops at that last one


class _Blends(NamedTuple):
    """Blends for given shares (fields as in `CornerBlends`)."""

    w: np.ndarray
    dU: np.ndarray
    cap: np.ndarray
    a_node: np.ndarray
    j_node: np.ndarray
    k_node: np.ndarray


def corner_blends(
    moves: MoveLimits,
    flags: NodeFlags,
    limits: AxisLimits,
    start: WindowStart | None,
    *,
    w_limit: np.ndarray | None = None,
) -> CornerBlends:
    """Blend every corner where the path does not stop; `start` is None for a fresh path.

    `w_limit` (n+1) [m] bounds the half-widths further (`fitted_widths`)."""
    n = len(moves.L)
    du = np.zeros((n + 1, moves.u.shape[1]))
    du[1:n] = moves.u[1:] - moves.u[:-1]
    ndu = np.sqrt(np.einsum("ij,ij->i", du, du))
    corner = ndu >= COLLINEAR
    corner[0] = corner[n] = False
    stop = flags.stop.copy()
    if start is not None:
        stop[len(start.w) - 1] = start.stop  # decided when it was committed; must not change
    alone = (flags.has_entries | flags.forced | (ndu > SHARP_CORNER)) & corner & ~stop
    share_in = np.full(n + 1, CHAIN_SHARE)
    share_out = np.full(n + 1, CHAIN_SHARE)
    # Next to a stop as well: a corner that ends up alone needs a body to get up to speed.
    keep_off = alone | stop
    share_in[1:] = np.where(keep_off[:-1], NEIGHBOUR_SHARE, share_in[1:])
    share_out[:-1] = np.where(keep_off[1:], NEIGHBOUR_SHARE, share_out[:-1])
    share_in = np.where(alone, BLEND_SHARE, share_in)
    share_out = np.where(alone, BLEND_SHARE, share_out)
    final = _blends(
        moves, limits, tol=flags.tol, du=du, ndu=ndu, corner=corner, stop=stop,
        share_in=share_in, share_out=share_out, start=start, w_limit=w_limit,
    )  # fmt: skip
    return CornerBlends(
        corner=corner,
        stop=stop,
        alone=alone,
        w=final.w,
        dU=final.dU,
        cap=np.where(stop, 0.0, final.cap),
        a_node=final.a_node,
        j_node=final.j_node,
        k_node=final.k_node,
    )


def _blends(  # noqa: PLR0913 (the corner geometry, its shares and the window; all keyword-only)
    moves: MoveLimits,
    limits: AxisLimits,
    *,
    tol: np.ndarray,
    du: np.ndarray,
    ndu: np.ndarray,
    corner: np.ndarray,
    stop: np.ndarray,
    share_in: np.ndarray,
    share_out: np.ndarray,
    start: WindowStart | None,
    w_limit: np.ndarray | None,
) -> _Blends:
    """Blend half-widths, blend vectors and corner speed caps for shares of the moves."""
    L, V = moves.L, moves.V
    L_in = np.concatenate(([0.0], L))
    L_out = np.concatenate((L, [0.0]))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.minimum(6.0 * tol / ndu, np.minimum(share_in * L_in, share_out * L_out))
    w = np.where(corner & ~stop, w, 0.0)
    if w_limit is not None:
        w = np.minimum(w, w_limit)
    if start is not None:
        w[: len(start.w)] = start.w
    dU = np.where((w > 0.0)[:, None], du, 0.0)
    zones = _alone_zones(L, w, dU)
    a_s, a_e, j_s, j_e, kick = zone_coefficients(L, w, dU, steps=limits.window_s > 0.0, zones=zones)
    zero = np.zeros((1, du.shape[1]))
    # Per node: its blend runs through the end zone before it and the start zone after.
    a_node = np.maximum(np.vstack((zero, a_e)), np.vstack((a_s, zero)))
    j_node = np.maximum(np.vstack((zero, j_e)), np.vstack((j_s, zero)))
    k_node = np.maximum(np.vstack((zero, kick)), np.vstack((kick, zero)))
    if limits.window_s > 0.0:
        k_node = _isolated_steps(zones, V * (3.0 * limits.period_s), k_node)
    V_in = np.concatenate(([np.inf], V))
    V_out = np.concatenate((V, [np.inf]))
    cap = limits.cruise_cap(a_node, j_node, 1.0, 1.0, k_node)
    cap = np.minimum(np.minimum(V_in, V_out), cap)
    return _Blends(w, dU, cap, a_node, j_node, k_node)


def fitted_widths(
    blends: CornerBlends,
    node: np.ndarray,
    v: np.ndarray,
    limits: AxisLimits,
    *,
    extended: np.ndarray,
    last: int,
) -> np.ndarray | None:
    """Half-widths [m] of the sharp corners blended alone at 1-D nodes (polyline nodes `node`)
    narrowed to what their planned speeds `v` [m/s] need, for the jerk profile; None where none
    narrows. Only `extended` ones (their blends count in no chain's limits) up to polyline node
    `last` (what the window commits: later windows see the same geometry beyond it).

    A corner blended alone is crossed at constant speed v over 2 w and its raw plan holds v
    for T beyond (`jerk_filter`). Where the plan crosses it below the speed its blend allows
    (the bodies next to it too short to hold a faster one for T, or braking), a narrower blend
    allows that speed too and takes less time: |dU_i| v^2 / w <= a_max_i and
    |dU_i| v^3 / w^2 <= j_max_i give the smallest w, its cost 2 w / v = 2 sqrt(|dU_i| v / j_i)
    falls with v where the tolerance's width costs 2 w_P / v. Planned again with these widths
    (and the same extended nodes), the corner keeps its speed (its cap is v) and its
    neighbours gain the room it gives up: every constraint relaxes, none tightens.
    """
    sharp = np.sqrt(np.einsum("ij,ij->i", blends.dU, blends.dU)) > SHARP_CORNER
    alone = blends.alone[node] & sharp[node] & extended & (node <= last)
    alone &= (blends.w[node] > 0.0) & (v > 0.0)
    if not limits.jerk or not np.any(alone):
        return None
    dU = np.abs(blends.dU[node[alone]])
    vq = v[alone][:, None] * (1.0 + WIDTH_MARGIN)
    need = np.max(
        np.maximum(dU * vq * vq / limits.a_max, np.sqrt(dU * vq**3 / limits.j_max)), axis=1
    )
    w_limit = np.full(len(blends.w), np.inf)
    narrower = need < NARROWER * blends.w[node[alone]]
    if not np.any(narrower):
        return None
    w_limit[node[alone][narrower]] = need[narrower]
    return w_limit


def _isolated_steps(zones: _Zones, reach: np.ndarray, k_node: np.ndarray) -> np.ndarray:
    """The curvature steps `k_node` (n+1, n_axes) [1/m] counted per node as the sampled jerk
    sees them where that is less (`AxisLimits.kick_jerk` weighs a node's value 3/2).

    A step lies next to a node: the end zone of move k-1 where its end blend runs alone ends
    at node k, the start zone of move k where its start blend runs alone starts there. The
    third differences of the positions see a step through a quadratic B-spline of 3 periods
    (peak 3/4 per period), so two steps count together only if both lie within the distance
    `reach` (n) [m] a sample travels in 3 periods at the move's speed limit. Where the overlap
    of both blends on each move next to node k is at least that long, the steps of other
    nodes lie beyond it and node k's own two count 3/4 each: half their sum, where
    `zone_coefficients` keeps the larger total of the moves next to it (two steps of 3/4)."""
    n = len(zones.overlap)
    if n < 2:
        return k_node
    ks, ke, overlap = zones.k_s, zones.k_e, zones.overlap
    isolated = np.zeros(n + 1, dtype=bool)
    isolated[1:n] = (overlap[:-1] >= reach[:-1]) & (overlap[1:] >= reach[1:])
    own = 0.5 * (ke[:-1] + ks[1:])  # the steps next to nodes 1..n-1
    k_inner = np.where(isolated[1:n, None], np.minimum(own, k_node[1:n]), k_node[1:n])
    return np.vstack((k_node[:1], k_inner, k_node[n:]))


class _Zones(NamedTuple):
    """Per move, where one blend runs alone at its start or end (`_alone_zones`)."""

    j_s: np.ndarray  # (n, na) [1/m^2] |d3x/ds3| where the start blend runs alone (else 0)
    j_e: np.ndarray  # (n, na) [1/m^2] the same for the end blend
    short_s: np.ndarray  # (n, 1) that zone is a curvature step (shorter than KICK_ZONE)
    short_e: np.ndarray  # (n, 1)
    k_s: np.ndarray  # (n, na) [1/m] the step it makes (0 where not short)
    k_e: np.ndarray  # (n, na) [1/m]
    overlap: np.ndarray  # (n,) [m] length where both blends run


def _alone_zones(L: np.ndarray, w: np.ndarray, du: np.ndarray) -> _Zones:
    """Per move: the slopes |d3x/ds3| where its start or end blend runs alone, the curvature
    steps those zones make where shorter than KICK_ZONE of the move, and the length where
    both blends overlap."""
    ws = w[:-1][:, None]
    we = w[1:][:, None]
    Lc = L[:, None]
    overlap = (ws > 0.0) & (we > 0.0) & (ws > Lc - we)
    with np.errstate(divide="ignore", invalid="ignore"):
        # A zone shorter than a rounding error of the move is none (equal neighbouring chords
        # give w_start + w_end = L up to rounding, and no stretch of a single blend between).
        slack = ZONE_SLACK * Lc
        alone_s = np.minimum(ws, Lc - we)  # length of the start blend alone
        alone_e = Lc - np.maximum(ws, Lc - we)
        start_only = (ws > 0.0) & (alone_s > slack)
        end_only = (we > 0.0) & (alone_e > slack)
        j_s = np.where(start_only, np.abs(du[:-1]) / (ws * ws), 0.0)
        j_e = np.where(end_only, np.abs(du[1:]) / (we * we), 0.0)
    short_s = overlap & (alone_s <= KICK_ZONE * Lc)
    short_e = overlap & (alone_e <= KICK_ZONE * Lc)
    ks = np.where(short_s, j_s * alone_s, 0.0)
    ke = np.where(short_e, j_e * alone_e, 0.0)
    both = np.where(overlap, ws + we - Lc, 0.0)[:, 0]
    return _Zones(j_s, j_e, short_s, short_e, ks, ke, both)


def zone_coefficients(
    L: np.ndarray,
    w: np.ndarray,
    du: np.ndarray,
    *,
    steps: bool = False,
    zones: _Zones | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Largest |d2x/ds2| and |d3x/ds3| per axis in the start and end blend zone of each move,
    and its curvature steps.

    On move k the blends of node k (start, sigma in [0, w_k]) and node k+1 (end, sigma in
    [L - w_k+1, L]) may overlap; there d2x/ds2 = dU_k h'_k + dU_k+1 h'_k+1 is linear in
    sigma between the zone ends and d3x/ds3 = dU_k h''_k + dU_k+1 h''_k+1 is constant on
    each part, so a few points bound them. With `steps` a part of one blend alone shorter
    than KICK_ZONE of the move (neighbouring chords of slightly different lengths) counts
    as a curvature step K = |d3x/ds3| * its length, spread over the move (K / L in d3x/ds3;
    the sampled jerk sees the step itself, `AxisLimits.kick_jerk`).
    Returns (a_start, a_end, j_start, j_end, steps K), (n, na) each; `zones` are those
    `_alone_zones` gives for the same arguments, where computed already.
    """
    ws = w[:-1][:, None]
    we = w[1:][:, None]
    dus = du[:-1]
    due = du[1:]
    Lc = L[:, None]

    def curvature(sigma: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            hs = np.where(ws > 0.0, np.maximum(ws - sigma, 0.0) / (ws * ws), 0.0)
            he = np.where(we > 0.0, np.maximum(sigma - (Lc - we), 0.0) / (we * we), 0.0)
        return np.abs(dus * hs + due * he)

    inner_start = np.minimum(ws, Lc)
    inner_end = np.maximum(Lc - we, 0.0)
    overlap = (ws > 0.0) & (we > 0.0) & (ws > Lc - we)
    a_start = np.maximum(curvature(np.zeros_like(ws)), curvature(inner_start))
    a_end = np.maximum(curvature(Lc), curvature(inner_end))
    a_start = np.where(overlap, np.maximum(a_start, curvature(inner_end)), a_start)
    a_end = np.where(overlap, np.maximum(a_end, curvature(inner_start)), a_end)
    j_s, j_e, short_s, short_e, ks, ke, _ = _alone_zones(L, w, du) if zones is None else zones
    with np.errstate(divide="ignore", invalid="ignore"):
        j_both = np.where(overlap, np.abs(due / (we * we) - dus / (ws * ws)), 0.0)
    kick = np.zeros_like(j_s)
    if steps:
        kick = ks + ke
        j_s = np.where(short_s, 0.0, j_s)
        j_e = np.where(short_e, 0.0, j_e)
        j_both = j_both + kick / Lc
    return a_start, a_end, np.maximum(j_s, j_both), np.maximum(j_e, j_both), kick
