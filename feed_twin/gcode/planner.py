"""Planner: interpreter items -> time-parameterised, jerk-limited multi-axis setpoints.

Stages, each pure: the interpreter's straight moves (arcs already chords) form a polyline in
machine coordinates. Each move k has a direction u_k and the limits along it

    V_k = min(F, min_i v_max_i/|u_ki|)     (G0: min_i rapid_i/|u_ki|)
    A_k = min_i a_max_i/|u_ki|,   J_k = min_i j_max_i/|u_ki|

so that the axis components u_ki * (ds/dt, d2s/dt2, d3s/dt3) stay within every axis's limits.

Corners (G64) are blended (see `profile`) with half-width w <= 6*tol/|dU| (deviation at most
tol) and a share of the neighbouring moves:
- a corner blended alone (sharp: |dU| > SHARP_CORNER, or with an event, or a forced break) takes
  at most BLEND_SHARE of each move and is crossed at constant speed
  v_c <= min(V_in, V_out, sqrt(a_max_i*w/|dU_i|), cbrt(j_max_i*w^2/|dU_i|));
- gentle corners (chords of an arc, CAM polylines) may take whole moves, so that neighbouring
  blends overlap into a chain whose curvature is continuous; a chain is a body of its own in
  the speed profile, with the axis limits shared between the curvature terms and s'' and s'''
  (`_chain_limits`).
A corner that is quicker to stop at than to round under the jerk limit becomes a stop. G61,
G9, dwells and stopping M-codes end a move at rest. Collinear joints with equal limits are
passed through. Every profile piece starts and ends at zero acceleration.

Look-ahead: a backward pass of braking bounds and a forward pass over the boundary speeds of up
to `lookahead_segments` moves, with the window's end at rest; the first half is committed,
sampled and yielded, the rest is planned again with the next moves. Committed speeds stay
reachable as constraints relax (the braking bound is monotonic), so the result is always
safe, and memory stays bounded.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from feed_twin.gcode import profile as prof
from feed_twin.gcode.config import NcConfig
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.interpreter import Event, Interpreter, Move, Stop
from feed_twin.gcode.lexer import Block, iter_source_lines, lex_line
from feed_twin.gcode.trajectory import NcEvent, SampledTrajectory

BLEND_SHARE = 0.4  # largest part of a move a corner blended alone may use
NEIGHBOUR_SHARE = 0.55  # the same for its neighbours, so that a straight piece stays between
CHAIN_SHARE = 1.0  # elsewhere: blends may reach the neighbouring corner and overlap
CHAIN_CUT = 1.3  # a chain is cut where its local speed cap changes by more than this factor
SHARP_CORNER = 0.25  # |u_out - u_in| above this (about 14 degrees) is a corner, not a curve
COLLINEAR = 1e-12  # |u_out - u_in| below this is a straight joint, not a corner


def iter_blocks(source: str | Path, config: NcConfig) -> tuple[str, Iterator[Block]]:
    """(file name, lazily lexed blocks) of a program path or text.

    A program that opens with a `%` line ends at the next `%` line (RS274/NGC); what follows
    is not read.
    """
    file, lines = iter_source_lines(source)

    def blocks() -> Iterator[Block]:
        block_delete = config.block_delete
        opened = None  # whether the first non-blank line was '%'
        for number, text in lines:
            stripped = text.strip()
            if stripped.startswith("%"):
                if opened:
                    return
                opened = opened is None
                continue
            if stripped and opened is None:
                opened = False
            block = lex_line(text, number, file=file, block_delete=block_delete)
            if block is not None:
                yield block

    return file, blocks()


def validate_program(source: str | Path, config: NcConfig) -> int:
    """Lex and interpret the whole program (the cheap first pass); return the move count.

    Raises `GcodeError` for the first problem, so nothing is emitted for a bad program.
    """
    file, blocks = iter_blocks(source, config)
    interpreter = Interpreter(config, file=file)
    n_blocks = 0
    n_moves = 0
    for block in blocks:
        n_blocks += 1
        if interpreter.ended:
            break
        for item in interpreter.block(block):
            if type(item) is Move:
                n_moves += 1
    if n_blocks == 0:
        raise GcodeError("the program is empty (no G-code blocks)", file=file)
    return n_moves


def plan_program_stream(source: str | Path, config: NcConfig) -> Iterator[SampledTrajectory]:
    """Yield the trajectory in consecutive chunks, planning with bounded look-ahead.

    The whole program is validated first (`validate_program`), so a bad program raises before
    the first chunk. Chunks share the sample grid t = k * interpolation_period_s.
    """
    validate_program(source, config)
    return _plan_chunks(source, config)


def plan_program(source: str | Path, config: NcConfig) -> SampledTrajectory:
    """Plan a whole program (path or text) and return all its samples.

    One pass: every error is raised before anything is returned.
    """
    return SampledTrajectory.concatenate(_plan_chunks(source, config))


def _plan_chunks(source: str | Path, config: NcConfig) -> Iterator[SampledTrajectory]:
    file, blocks = iter_blocks(source, config)
    counted = _Counted(blocks)
    planner = _StreamPlanner(config)
    interpreter = Interpreter(config, file=file)
    limit = config.lookahead_segments
    for item in interpreter.run(counted):
        planner.add(item)
        if planner.pending_moves() >= limit:
            chunk = planner.plan(final=False)
            if chunk is not None:
                yield chunk
    if counted.count == 0:
        raise GcodeError("the program is empty (no G-code blocks)", file=file)
    yield planner.plan(final=True)


class _Counted:
    """Iterates blocks and counts them (an empty program is an error)."""

    def __init__(self, blocks: Iterator[Block]) -> None:
        self.blocks = blocks
        self.count = 0

    def __iter__(self) -> Iterator[Block]:
        for block in self.blocks:
            self.count += 1
            yield block


class _StreamPlanner:
    """Collects moves and node entries; plans windows; keeps only what is not yet committed."""

    def __init__(self, config: NcConfig) -> None:
        self.config = config
        self.axes = config.axis_names
        self.v_max = np.array(config.v_max)
        self.rapid = np.array(config.rapid)
        self.a_max = np.array(config.a_max)
        self.j_max = np.array(config.j_max)
        self.jerk = config.profile == "jerk"
        self.period = config.interpolation_period_s
        self.forced = max(2, config.lookahead_segments // 4)
        # Listed moves: the not yet committed ones, preceded by one committed context move
        # (its end blend reaches into the next chunk) once anything was committed.
        self.points: list[tuple[float, ...]] = [config.start_position]
        self.lines: list[int] = []
        self.rapids: list[bool] = []
        self.feeds: list[float] = []
        self.tols: list[float] = []
        self.g0 = 0  # global index of listed move 0
        self.has_context = False
        self.stops: set[int] = set()  # global node indices where the path is at rest
        self.entries: dict[int, list[Event | Stop]] = {}  # global node -> events and dwells
        self.v_first = 0.0
        self.w_first = 0.0  # blend half-width at the first node of the next window
        self.first_stop = False  # whether the path stops there
        self.t_s = 0.0
        self.k_next = 0
        self.last_line = 0

    def pending_moves(self) -> int:
        return len(self.lines) - (1 if self.has_context else 0)

    def add(self, item: Move | Stop | Event) -> None:
        node = self.g0 + len(self.lines)
        if type(item) is Move:
            self.points.append(item.end_m)
            self.lines.append(item.line)
            self.rapids.append(item.rapid)
            self.feeds.append(item.feed_m_s)
            self.tols.append(item.tolerance_m)
            if item.exact_stop:
                self.stops.add(node + 1)
            return
        self.entries.setdefault(node, []).append(item)
        if type(item) is Stop or item.stops:
            self.stops.add(node)

    def plan(self, *, final: bool) -> SampledTrajectory | None:
        n = len(self.lines)
        if n == 0:
            return self._plan_standstill()
        first = 1 if self.has_context else 0
        P = np.array(self.points)
        delta = np.diff(P, axis=0)
        L = np.sqrt(np.einsum("ij,ij->i", delta, delta))
        u = delta / L[:, None]
        absu = np.abs(u)
        with np.errstate(divide="ignore"):
            v_feed = np.min(self.v_max / absu, axis=1)
            v_rapid = np.min(self.rapid / absu, axis=1)
            A = np.min(self.a_max / absu, axis=1)
            J = np.min(self.j_max / absu, axis=1)
        rapids = np.array(self.rapids)
        V = np.where(rapids, v_rapid, np.minimum(np.array(self.feeds), v_feed))
        if not self.jerk:
            J = np.full(n, np.inf)

        # Nodes 0..n; node j is the start of listed move j.
        g = self.g0
        na = len(self.axes)
        du = np.zeros((n + 1, na))
        du[1:n] = u[1:] - u[:-1]
        ndu = np.sqrt(np.einsum("ij,ij->i", du, du))
        corner = ndu >= COLLINEAR
        corner[0] = corner[n] = False
        stop = np.zeros(n + 1, dtype=bool)
        stop[0] = not self.has_context
        stop[n] = True
        for node in self.stops:
            if 0 <= node - g <= n:
                stop[node - g] = True
        has_entries = np.zeros(n + 1, dtype=bool)
        for node in self.entries:
            if 0 <= node - g <= n:
                has_entries[node - g] = True
        forced = (np.arange(n + 1) + g) % self.forced == 0
        tol = np.zeros(n + 1)
        tol[1:n] = self.tols[:-1]
        L_in = np.concatenate(([0.0], L))
        L_out = np.concatenate((L, [0.0]))
        V_in = np.concatenate(([np.inf], V))
        V_out = np.concatenate((V, [np.inf]))

        def blends(share_in: np.ndarray, share_out: np.ndarray) -> tuple[np.ndarray, ...]:
            """Blend half-widths, blend vectors and corner speed caps for shares of the moves."""
            with np.errstate(divide="ignore", invalid="ignore"):
                w = np.minimum(6.0 * tol / ndu, np.minimum(share_in * L_in, share_out * L_out))
            w = np.where(corner & ~stop, w, 0.0)
            if self.has_context:
                w[first] = self.w_first
            dU = np.where((w > 0.0)[:, None], du, 0.0)
            a_s, a_e, j_s, j_e = self._zone_coefficients(L, w, dU)
            zero = np.zeros((1, na))
            # Per node: its blend runs through the end zone before it and the start zone after.
            a_node = np.maximum(np.vstack((zero, a_e)), np.vstack((a_s, zero)))
            j_node = np.maximum(np.vstack((zero, j_e)), np.vstack((j_s, zero)))
            cap = np.minimum(np.minimum(V_in, V_out), self._cruise_cap(a_node, j_node, 1.0, 1.0))
            return w, dU, cap, a_node, j_node

        # A tight corner is quicker to stop at than to round within the tolerance under a jerk
        # limit; stop there when the local time estimate (with single blends) says so.
        single = np.full(n + 1, BLEND_SHARE)
        w, _, cap, _, _ = blends(single, single)
        if n > 1:
            inner = slice(1, n)
            stop[inner] |= (w[inner] > 0.0) & (
                self._corner_cost(cap[inner], w[inner], V, A, J)
                >= self._corner_cost(0.0 * cap[inner], 0.0 * w[inner], V, A, J)
            )
        if self.has_context:
            stop[first] = self.first_stop  # decided when it was committed; must not change
        # Sharp corners, corners with events and forced breaks are blended alone (BLEND_SHARE
        # of each move, and their neighbours keep off: NEIGHBOUR_SHARE). Elsewhere neighbouring
        # blends may reach each other and overlap into chains, so that a finely divided curve
        # keeps a continuous curvature instead of one that rises and falls on every move.
        alone = (has_entries | forced | (ndu > SHARP_CORNER)) & corner & ~stop
        share_in = np.full(n + 1, CHAIN_SHARE)
        share_out = np.full(n + 1, CHAIN_SHARE)
        # Next to a stop as well: a corner that ends up alone needs a body to get up to speed.
        keep_off = alone | stop
        share_in[1:] = np.where(keep_off[:-1], NEIGHBOUR_SHARE, share_in[1:])
        share_out[:-1] = np.where(keep_off[1:], NEIGHBOUR_SHARE, share_out[:-1])
        share_in = np.where(alone, BLEND_SHARE, share_in)
        share_out = np.where(alone, BLEND_SHARE, share_out)
        w, du, cap, a_node, j_node = blends(share_in, share_out)
        cap = np.where(stop, 0.0, cap)

        same_limits = np.zeros(n + 1, dtype=bool)
        same_limits[1:n] = (V[:-1] == V[1:]) & (A[:-1] == A[1:]) & (J[:-1] == J[1:])
        passing = ~corner & same_limits & ~(stop | has_entries | forced)
        passing &= ~(w > 0.0)
        passing[: first + 1] = False
        nodes_b = np.flatnonzero(~passing)
        nodes_b = nodes_b[nodes_b >= first]
        # Chains: neighbouring corners whose blends meet leave no straight body between them.
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
        local = self._cruise_cap(a_node[nodes_b], j_node[nodes_b], 0.5, 1.0 / 3.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = local[1:] / local[:-1]  # inf/inf (straight stretches) gives nan: no cut
        cut = np.zeros(len(nodes_b), dtype=bool)
        cut[1:] = (ratio > CHAIN_CUT) | (ratio < 1.0 / CHAIN_CUT)
        cut &= chained & (in_group > first_of) & (in_group < last_of)

        # 1-D nodes: a single corner (crossed at constant speed over its blend), or the entry,
        # the cuts and the exit of a chain (bodies of their own with shares of the limits kept
        # for the curvature). Bodies join consecutive 1-D nodes.
        emit = ~chained | (in_group == first_of) | (in_group == last_of) | cut
        pos_q = np.flatnonzero(emit)
        kind_q = np.where(
            ~chained[pos_q],
            0,
            np.where(
                in_group[pos_q] == first_of[pos_q],
                1,
                np.where(in_group[pos_q] == last_of[pos_q], 2, 3),
            ),
        )  # 0 single, 1 chain entry, 2 chain exit, 3 cut inside a chain
        node_q = nodes_b[pos_q]
        S = np.concatenate(([0.0], np.cumsum(L)))
        sa = np.where(kind_q == 0, S[node_q] - w[node_q], S[node_q])
        sa = np.where(kind_q == 1, S[node_q] - w[node_q], sa)
        sa = np.where(kind_q == 2, S[node_q] + w[node_q], sa)
        sb = np.where(kind_q == 0, S[node_q] + w[node_q], sa)
        if len(node_q) < 2:
            return self._plan_standstill() if final else None
        in_chain = (kind_q[:-1] == 1) | (kind_q[:-1] == 3)
        Vc, Ac, Jc = self._chain_limits(nodes_b, pos_q, a_node, j_node, u, V)
        cap_q = cap[node_q].copy()
        cap_q[1:] = np.where(in_chain, np.minimum(cap_q[1:], Vc), cap_q[1:])
        cap_q[:-1] = np.where(in_chain, np.minimum(cap_q[:-1], Vc), cap_q[:-1])
        cap_q = np.where(kind_q == 0, cap[node_q], cap_q)
        length = np.maximum(sa[1:] - sb[:-1], 0.0)
        if not final:
            # The window's end is at rest for now; the next window may put a blend there, which
            # takes up to the whole last move. Stopping before it keeps every speed planned now
            # reachable later (look-ahead only ever relaxes constraints).
            length[-1] = max(length[-1] - CHAIN_SHARE * L[n - 1], 0.0)
        pairs = np.column_stack((node_q[:-1], node_q[1:])).ravel()
        pad = np.array([np.inf])
        Vb = np.minimum.reduceat(np.concatenate((V, pad)), pairs)[::2]
        Ab = np.minimum.reduceat(np.concatenate((A, pad)), pairs)[::2]
        Jb = np.minimum.reduceat(np.concatenate((J, pad)), pairs)[::2]
        Vb = np.where(in_chain, Vc, Vb)
        Ab = np.where(in_chain, Ac, Ab)
        Jb = np.where(in_chain, Jc, Jb)
        speeds = prof.plan_speeds(cap_q, length, Ab, Jb, self.jerk, self.v_first)
        vp, t_up, t_cruise, t_down = prof.body_profiles(speeds, length, Vb, Ab, Jb, self.jerk)

        m = len(length)
        if final:
            q_commit = m
        else:
            # Commit up to a single corner well inside the window, so that the next window
            # starting there sees the same geometry around it.
            half = first + (n - first) // 2
            candidates = np.flatnonzero(
                (kind_q[1:] == 0) & (node_q[1:] <= half) & (node_q[1:] + 3 < n)
            )
            if len(candidates) == 0:
                return None  # nothing safely committable yet: wait for more moves
            q_commit = int(candidates[-1]) + 1
        q = np.arange(q_commit)
        nodes = node_q[: q_commit + 1]
        v_node = speeds[: q_commit + 1]

        # Three pieces per 1-D node: hold (dwells, filled below), cruise (blend), body.
        n_pieces = 3 * q_commit + 1
        kind = np.full(n_pieces, prof.HOLD, dtype=np.int64)
        dur = np.zeros(n_pieces)
        s0 = np.zeros(n_pieces)
        v0 = np.zeros(n_pieces)
        vpk = np.zeros(n_pieces)
        v1 = np.zeros(n_pieces)
        Ak = np.ones(n_pieces)
        Jk = np.ones(n_pieces)
        tu = np.zeros(n_pieces)
        tc = np.zeros(n_pieces)
        piece_line = np.full(n_pieces, -1, dtype=np.int64)
        # First move each piece runs on: a blend or a chain starts on the move before its node.
        before = np.maximum(nodes[:-1] - 1, 0)
        piece_seg = np.zeros(n_pieces, dtype=np.int64)
        piece_seg[3 * q] = before
        piece_seg[3 * q + 1] = before
        piece_seg[3 * q + 2] = np.where(
            kind_q[:q_commit] == 1, before, np.minimum(nodes[:-1], n - 1)
        )
        piece_seg[-1] = n - 1
        cruise = 3 * q + 1
        body = 3 * q + 2
        kind[cruise] = prof.CRUISE
        span = sb[:q_commit] - sa[:q_commit]
        with np.errstate(divide="ignore", invalid="ignore"):
            dur[cruise] = np.where(span > 0.0, span / v_node[:-1], 0.0)
        s0[cruise] = sa[:q_commit]
        v0[cruise] = v_node[:-1]
        s0[3 * q] = sa[:q_commit]
        kind[body] = prof.BODY
        dur[body] = t_up[:q_commit] + t_cruise[:q_commit] + t_down[:q_commit]
        s0[body] = sb[:q_commit]
        v0[body] = v_node[:-1]
        vpk[body] = vp[:q_commit]
        v1[body] = v_node[1:]
        Ak[body] = Ab[:q_commit]
        Jk[body] = Jb[:q_commit] if self.jerk else 1.0
        tu[body] = t_up[:q_commit]
        tc[body] = t_cruise[:q_commit]
        end_node = nodes[-1]
        s0[-1] = sa[q_commit]

        # Dwells and events: only at the (few) nodes that have entries.
        extra_key: list[float] = []
        extra_dur: list[float] = []
        extra_s: list[float] = []
        extra_line: list[int] = []
        extra_node: list[int] = []
        timed: list[tuple[int, float, Event]] = []  # (piece slot, offset within node, event)
        emit_nodes = list(nodes[:-1]) + ([end_node] if final else [])
        emit_kinds = list(kind_q[: len(emit_nodes)])
        for slot, (j, kind_j) in enumerate(zip(emit_nodes, emit_kinds, strict=True)):
            entries = self.entries.pop(int(j) + g, None) if kind_j == 0 else None
            if not entries:
                continue
            offset = 0.0
            for i, entry in enumerate(entries):
                if type(entry) is Stop:
                    extra_key.append(3 * slot - 0.5 + 0.5 * i / len(entries))
                    extra_dur.append(entry.dwell_s)
                    extra_s.append(S[j])
                    extra_line.append(entry.line)
                    extra_node.append(int(j))
                    offset += entry.dwell_s
                else:
                    timed.append((slot, offset, entry))
        key = np.arange(n_pieces, dtype=float)
        if extra_key:
            key = np.concatenate((key, extra_key))
            kind = np.concatenate((kind, np.full(len(extra_key), prof.HOLD)))
            dur = np.concatenate((dur, extra_dur))
            s0 = np.concatenate((s0, extra_s))
            zeros = np.zeros(len(extra_key))
            v0, vpk, v1, tu, tc = (np.concatenate((x, zeros)) for x in (v0, vpk, v1, tu, tc))
            piece_seg = np.concatenate((piece_seg, np.maximum(np.array(extra_node) - 1, 0)))
            Ak = np.concatenate((Ak, zeros + 1.0))
            Jk = np.concatenate((Jk, zeros + 1.0))
            piece_line = np.concatenate((piece_line, extra_line))
            order = np.argsort(key, kind="stable")
            key, kind, dur, s0, v0, vpk, v1, Ak, Jk, tu, tc, piece_line, piece_seg = (
                x[order]
                for x in (key, kind, dur, s0, v0, vpk, v1, Ak, Jk, tu, tc, piece_line, piece_seg)
            )
        if not np.all(np.isfinite(dur)):
            raise RuntimeError("planner error: a corner blend planned at rest (please report)")
        t0 = self.t_s + np.concatenate(([0.0], np.cumsum(dur)[:-1]))
        t_end = self.t_s + float(np.sum(dur))

        events: list[NcEvent] = []
        for slot, offset, entry in timed:
            # Node time: the start of its dwells, or the middle of its blend.
            k_hold = int(np.searchsorted(key, 3 * slot - 0.5))
            start = t0[k_hold] if k_hold < len(t0) else t_end
            cruise_slot = int(np.searchsorted(key, 3 * slot + 1))
            if slot < q_commit and dur[cruise_slot] > 0.0:
                start = t0[cruise_slot] + 0.5 * dur[cruise_slot]
            events.append(
                NcEvent(float(start + offset), entry.line, entry.kind, entry.value, entry.text)
            )

        if final:
            k_stop = math.ceil(t_end / self.period - 1e-9) + 1
        else:
            k_stop = math.ceil(t_end / self.period - 1e-12)
            k_stop = max(k_stop, self.k_next)
        times = np.arange(self.k_next, k_stop) * self.period
        s, sd, sdd, piece = prof.sample_pieces(
            times, kind, t0, dur, s0, v0, vpk, v1, Ak, Jk, tu, tc, self.jerk
        )
        w_start = w[:n]
        w_end = w[1:]
        pos, vel, acc, seg = prof.evaluate_path(
            s,
            sd,
            sdd,
            S[:-1],
            L,
            P[:-1],
            P[1:],
            u,
            w_start,
            du[:n],
            w_end,
            du[1:],
            piece_seg[piece],
        )
        lines = np.array(self.lines, dtype=np.int64)[seg]
        held = piece_line[piece]
        lines = np.where(held >= 0, held, lines)
        chunk = SampledTrajectory(
            t_s=times,
            axes=self.axes,
            pos_m=pos,
            vel_m_s=vel,
            acc_m_s2=acc,
            line=lines,
            events=tuple(events),
        )
        self.k_next = k_stop
        self.t_s = t_end
        self.v_first = float(speeds[q_commit])
        if not final:
            keep = int(end_node) - 1  # the move that ends at the commit node stays as context
            del self.points[:keep]
            del self.lines[:keep]
            del self.rapids[:keep]
            del self.feeds[:keep]
            del self.tols[:keep]
            self.g0 += keep
            self.has_context = True
            self.w_first = float(w[end_node])
            self.first_stop = bool(stop[end_node])
            self.stops = {node for node in self.stops if node >= self.g0 + 1}
        return chunk

    def _zone_coefficients(
        self, L: np.ndarray, w: np.ndarray, du: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Largest |d2x/ds2| and |d3x/ds3| per axis in the start and end blend zone of each move.

        On move k the blends of node k (start, sigma in [0, w_k]) and node k+1 (end, sigma in
        [L - w_k+1, L]) may overlap; there d2x/ds2 = dU_k h'_k + dU_k+1 h'_k+1 is linear in
        sigma between the zone ends and d3x/ds3 = dU_k h''_k + dU_k+1 h''_k+1 is constant on
        each part, so a few points bound them. Returns (a_start, a_end, j_start, j_end), (n, na).
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
        with np.errstate(divide="ignore", invalid="ignore"):
            start_only = (ws > 0.0) & (np.minimum(ws, Lc - we) > 0.0)
            end_only = (we > 0.0) & (Lc - np.maximum(ws, Lc - we) > 0.0)
            j_s = np.where(start_only, np.abs(dus) / (ws * ws), 0.0)
            j_e = np.where(end_only, np.abs(due) / (we * we), 0.0)
            j_both = np.where(overlap, np.abs(due / (we * we) - dus / (ws * ws)), 0.0)
        return a_start, a_end, np.maximum(j_s, j_both), np.maximum(j_e, j_both)

    def _cruise_cap(
        self, a_coef: np.ndarray, j_coef: np.ndarray, a_share: float, j_share: float
    ) -> np.ndarray:
        """Highest speed v with coef*v^2 <= a_share*a_max and coef*v^3 <= j_share*j_max."""
        with np.errstate(divide="ignore", invalid="ignore"):
            cap = np.min(
                np.where(a_coef > 0.0, np.sqrt(a_share * self.a_max / a_coef), np.inf), axis=-1
            )
            if self.jerk:
                j_cap = np.where(j_coef > 0.0, np.cbrt(j_share * self.j_max / j_coef), np.inf)
                cap = np.minimum(cap, np.min(j_cap, axis=-1))
        return cap

    def _chain_limits(
        self,
        nodes_b: np.ndarray,
        pos_q: np.ndarray,
        a_node: np.ndarray,
        j_node: np.ndarray,
        u: np.ndarray,
        V: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Speed cap, acceleration and jerk [SI] of the body from each 1-D node to the next,
        as if it ran along a chain of overlapping blends (used where it does).

        Along a chain the axis motion is d(s) ds/dt with d a convex combination of the move
        directions (|d_i| <= max |u_i|), and
            a_i = d_i s'' + d'_i (s')^2,   j_i = d_i s''' + 3 d'_i s' s'' + d''_i (s')^3.
        Half of each axis's acceleration goes to the curvature term (cap V) and half to s''
        (A); a third of its jerk to each of the three jerk terms (V, then A, then J). The body
        from node p to node q meets the blends of nodes p..q, hence the maxima over them.
        """
        absu = np.abs(u)
        zero = np.zeros((1, absu.shape[1]))
        u_node = np.maximum(np.vstack((zero, absu)), np.vstack((absu, zero)))
        v_node = np.minimum(np.concatenate(([np.inf], V)), np.concatenate((V, [np.inf])))
        pairs = np.column_stack((pos_q[:-1], pos_q[1:] + 1)).ravel()

        def over_bodies(values: np.ndarray, reduce) -> np.ndarray:
            padded = np.concatenate((values[nodes_b], values[nodes_b][-1:]))
            return reduce.reduceat(padded, pairs, axis=0)[::2]

        a_g = over_bodies(a_node, np.maximum)
        j_g = over_bodies(j_node, np.maximum)
        u_g = over_bodies(u_node, np.maximum)
        Vc = np.minimum(over_bodies(v_node, np.minimum), self._cruise_cap(a_g, j_g, 0.5, 1.0 / 3.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            Ac = np.min(np.where(u_g > 0.0, 0.5 * self.a_max / u_g, np.inf), axis=1)
            if self.jerk:
                cross = self.j_max / (9.0 * a_g * Vc[:, None])
                Ac = np.minimum(Ac, np.min(np.where(a_g > 0.0, cross, np.inf), axis=1))
                Jc = np.min(np.where(u_g > 0.0, self.j_max / (3.0 * u_g), np.inf), axis=1)
            else:
                Jc = np.full(len(Vc), np.inf)
        return Vc, Ac, Jc

    def _corner_cost(
        self, v: np.ndarray, w: np.ndarray, V: np.ndarray, A: np.ndarray, J: np.ndarray
    ) -> np.ndarray:
        """Time lost at each interior corner against cruising at the neighbouring caps.

        Slowing from V to v takes T(V - v) and covers (V + v)/2 * T, which at V would take
        (V + v)/(2V) * T: the loss is T * (V - v)/(2V). The blend itself adds 2w/v - 2w/V.
        """
        loss = np.zeros_like(v)
        for V_s, A_s, J_s in ((V[:-1], A[:-1], J[:-1]), (V[1:], A[1:], J[1:])):
            dv = np.maximum(V_s - v, 0.0)
            if self.jerk:
                short = dv * J_s < A_s * A_s
                with np.errstate(invalid="ignore"):
                    T = np.where(short, 2.0 * np.sqrt(dv / J_s), dv / A_s + A_s / J_s)
            else:
                T = dv / A_s
            loss += T * dv / (2.0 * V_s)
        V_ref = np.minimum(V[:-1], V[1:])
        with np.errstate(divide="ignore", invalid="ignore"):
            blend = np.where(w > 0.0, 2.0 * w / v - 2.0 * w / V_ref, 0.0)
        return loss + blend

    def _plan_standstill(self) -> SampledTrajectory:
        """A program (or tail) without moves: only dwells and events at the current point."""
        node = self.g0 + len(self.lines)
        entries = self.entries.pop(node, [])
        t = self.t_s
        events = []
        spans: list[tuple[float, float, int]] = []
        for entry in entries:
            if type(entry) is Stop:
                spans.append((t, t + entry.dwell_s, entry.line))
                t += entry.dwell_s
            else:
                events.append(NcEvent(t, entry.line, entry.kind, entry.value, entry.text))
        k_stop = math.ceil(t / self.period - 1e-9) + 1
        times = np.arange(self.k_next, k_stop) * self.period
        n = len(times)
        lines = np.full(n, self.lines[-1] if self.lines else 0, dtype=np.int64)
        for a, b, line in spans:
            lines[(times >= a) & (times < b)] = line
        position = np.array(self.points[-1])
        self.k_next = k_stop
        self.t_s = t
        return SampledTrajectory(
            t_s=times,
            axes=self.axes,
            pos_m=np.tile(position, (n, 1)),
            vel_m_s=np.zeros((n, len(self.axes))),
            acc_m_s2=np.zeros((n, len(self.axes))),
            line=lines,
            events=tuple(events),
        )
