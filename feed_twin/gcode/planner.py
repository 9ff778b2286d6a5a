"""Planner: interpreter items -> time-parameterised, jerk-limited multi-axis setpoints.

Stages, each pure: the interpreter's straight moves (arcs already chords) form a polyline in
machine coordinates. Each move k has a direction u_k and the limits along it

    V_k = min(F, min_i v_max_i/|u_ki|)     (G0: min_i rapid_i/|u_ki|)
    A_k = min_i a_max_i/|u_ki|,   J_k = min_i j_max_i/|u_ki|

so that the axis components u_ki * (ds/dt, d2s/dt2, d3s/dt3) stay within every axis's limits.
Corners (G64) are blended (see `profile`): blend half-width
w = min(6*tol/|dU|, 0.4*L_in, 0.4*L_out) and corner speed
v_c = min(V_in, V_out, sqrt(a_max_i*w/|dU_i|), cbrt(j_max_i*w^2/|dU_i|)), so the blend stays
within the path tolerance and the axis limits. G61, G9, dwells and stopping M-codes end a
move at rest. Collinear joints with equal limits are passed through without a boundary.

Look-ahead: a backward and a forward pass over the boundary speeds of up to
`lookahead_segments` moves, with the window's last boundary at rest; the first half is
committed, sampled and yielded, the rest is planned again with the next moves. A committed
speed is never raised later, so the result is always safe, and memory stays bounded.
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

BLEND_SHARE = 0.4  # largest part of a move one corner blend may use (two corners: 80 %)
COLLINEAR = 1e-12  # |u_out - u_in| below this is a straight joint, not a corner


def iter_blocks(source: str | Path, config: NcConfig) -> tuple[str, Iterator[Block]]:
    """(file name, lazily lexed blocks) of a program path or text."""
    file, lines = iter_source_lines(source)

    def blocks() -> Iterator[Block]:
        block_delete = config.block_delete
        for number, text in lines:
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
        self.v_max = np.array([a.v_max_m_s for a in config.axes])
        self.rapid = np.array([a.rapid_m_s for a in config.axes])
        self.a_max = np.array([a.a_max_m_s2 for a in config.axes])
        self.j_max = np.array([a.j_max_m_s3 for a in config.axes])
        self.jerk = config.profile == "jerk"
        self.period = config.interpolation_period_s
        self.forced = max(2, config.lookahead_segments // 4)
        # Listed moves: the not yet committed ones, preceded by one committed context move
        # (its end blend reaches into the next chunk) once anything was committed.
        self.points: list[tuple[float, ...]] = [tuple(config.start_position_m)]
        self.lines: list[int] = []
        self.rapids: list[bool] = []
        self.feeds: list[float] = []
        self.tols: list[float] = []
        self.g0 = 0  # global index of listed move 0
        self.has_context = False
        self.stops: set[int] = set()  # global node indices where the path is at rest
        self.entries: dict[int, list[Event | Stop]] = {}  # global node -> events and dwells
        self.v_first = 0.0
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
        cap = np.zeros(n + 1)
        w = np.zeros(n + 1)
        du = np.zeros((n + 1, len(self.axes)))
        if n > 1:
            du[1:n] = u[1:] - u[:-1]
            ndu = np.sqrt(np.einsum("ij,ij->i", du[1:n], du[1:n]))
            tol = np.array(self.tols[:-1])
            corner = ndu >= COLLINEAR
            with np.errstate(divide="ignore", invalid="ignore"):
                wj = np.minimum(6.0 * tol / ndu, BLEND_SHARE * np.minimum(L[:-1], L[1:]))
                wj = np.where(corner, wj, 0.0)
                adu = np.abs(du[1:n])
                v_acc = np.min(np.sqrt(self.a_max * wj[:, None] / adu), axis=1)
                v_jerk = np.min(np.cbrt(self.j_max * (wj * wj)[:, None] / adu), axis=1)
            cj = np.minimum(V[:-1], V[1:])
            cj = np.where(corner, np.minimum(cj, v_acc), cj)
            if self.jerk:
                cj = np.where(corner, np.minimum(cj, v_jerk), cj)
            # A tight corner is quicker to stop at than to round within the tolerance under a
            # jerk limit; stop there when the local time estimate says so.
            stop_here = corner & (
                self._corner_cost(cj, wj, V, A, J) >= self._corner_cost(0.0 * cj, 0.0 * wj, V, A, J)
            )
            cj = np.where(stop_here, 0.0, cj)
            wj = np.where(stop_here, 0.0, wj)
            cap[1:n] = cj
            w[1:n] = wj
            du[1:n] = np.where((corner & ~stop_here)[:, None], du[1:n], 0.0)
            same_limits = (V[:-1] == V[1:]) & (A[:-1] == A[1:]) & (J[:-1] == J[1:])
            passing = np.zeros(n + 1, dtype=bool)
            passing[1:n] = ~corner & same_limits
        else:
            passing = np.zeros(n + 1, dtype=bool)
        g = self.g0
        for node in list(self.stops):
            j = node - g
            if 0 <= j <= n:
                cap[j] = 0.0
                w[j] = 0.0
                du[j] = 0.0
        for node in self.entries:
            j = node - g
            if 0 <= j <= n:
                passing[j] = False
        passing[: first + 1] = False
        passing[n] = False
        forced = (np.arange(n + 1) + g) % self.forced == 0
        passing &= ~forced
        cap[n] = 0.0
        w[n] = 0.0
        du[n] = 0.0
        if not self.has_context:
            cap[0] = 0.0
            w[0] = 0.0

        boundaries = np.flatnonzero(~passing)
        boundaries = boundaries[boundaries >= first]
        if len(boundaries) < 2:
            return self._plan_standstill() if final else None
        S = np.concatenate(([0.0], np.cumsum(L)))
        b0 = boundaries[:-1]
        b1 = boundaries[1:]
        length = S[b1] - S[b0] - w[b0] - w[b1]
        if not final:
            # The window's end is at rest for now; the next window may put a blend there, which
            # takes up to BLEND_SHARE of the last move. Stopping before that share keeps every
            # speed planned now reachable later (look-ahead only ever relaxes constraints).
            length[-1] -= BLEND_SHARE * L[n - 1]
        length = np.maximum(length, 0.0)
        # Bodies take the tightest limits of their moves (equal by construction, up to rounding).
        Vb = np.minimum.reduceat(V, b0)
        Ab = np.minimum.reduceat(A, b0)
        Jb = np.minimum.reduceat(J, b0)
        speeds = prof.plan_speeds(cap[boundaries], length, Ab, Jb, self.jerk, self.v_first)
        vp, t_up, t_cruise, t_down = prof.body_profiles(speeds, length, Vb, Ab, Jb, self.jerk)

        m = len(b0)
        if final:
            q_commit = m
        else:
            half = first + (n - first) // 2
            candidates = np.flatnonzero(b1 <= half)
            q_commit = int(candidates[-1]) + 1 if len(candidates) else 1
            if q_commit >= m:
                return None  # nothing but the provisional last body: wait for more moves
        q = np.arange(q_commit)
        nodes = boundaries[: q_commit + 1]
        v_node = speeds[: q_commit + 1]

        # Three pieces per boundary node: hold (dwells, filled below), cruise (blend), body.
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
        # First move each piece runs on: a blend starts on the move before its node.
        piece_seg = np.zeros(n_pieces, dtype=np.int64)
        piece_seg[3 * q] = np.maximum(nodes[:-1] - 1, 0)
        piece_seg[3 * q + 1] = np.maximum(nodes[:-1] - 1, 0)
        piece_seg[3 * q + 2] = np.minimum(nodes[:-1], n - 1)
        piece_seg[-1] = n - 1
        w_n = w[nodes[:-1]]
        s_node = S[nodes[:-1]]
        cruise = 3 * q + 1
        body = 3 * q + 2
        kind[cruise] = prof.CRUISE
        with np.errstate(divide="ignore", invalid="ignore"):
            dur[cruise] = np.where(w_n > 0.0, 2.0 * w_n / v_node[:-1], 0.0)
        s0[cruise] = s_node - w_n
        v0[cruise] = v_node[:-1]
        s0[3 * q] = s_node
        kind[body] = prof.BODY
        dur[body] = t_up[:q_commit] + t_cruise[:q_commit] + t_down[:q_commit]
        s0[body] = s_node + w_n
        v0[body] = v_node[:-1]
        vpk[body] = vp[:q_commit]
        v1[body] = v_node[1:]
        Ak[body] = Ab[:q_commit]
        Jk[body] = Jb[:q_commit] if self.jerk else 1.0
        tu[body] = t_up[:q_commit]
        tc[body] = t_cruise[:q_commit]
        end_node = nodes[-1]
        s0[-1] = S[end_node]

        # Dwells and events: only at the (few) nodes that have entries.
        extra_key: list[float] = []
        extra_dur: list[float] = []
        extra_s: list[float] = []
        extra_line: list[int] = []
        extra_node: list[int] = []
        timed: list[tuple[int, float, Event]] = []  # (piece slot, offset within node, event)
        emit_nodes = list(nodes[:-1]) + ([end_node] if final else [])
        for slot, j in enumerate(emit_nodes):
            entries = self.entries.pop(int(j) + g, None)
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
            self.stops = {node for node in self.stops if node >= self.g0 + 1}
        return chunk

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
