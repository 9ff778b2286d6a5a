"""Planner: interpreter items -> time-parameterised, jerk-limited multi-axis setpoints.

The interpreter's straight moves (arcs already chords) form a polyline in machine
coordinates. A window of listed moves goes through five stages, each pure and in its own file,
after two for the jerk profile: the vertices of CAM polylines smoothed within a quarter of the
tolerance (`plan_smoothing`) and forced breaks of long chains placed where they cost least
(`plan_breaks`), both frozen once committed:

1. move limits (`plan_limits`): length, direction and the speed, acceleration and jerk along
   each move that keep every axis within its limits;
2. corner blends (`plan_blends`): blend half-widths within the path tolerance and corner
   speeds; every G64 corner is rounded (with the jerk filter, a sharp corner the plan
   crosses slower than its blend allows is planned again with a narrower one,
   `fitted_widths`);
3. chains (`plan_chains`): overlapping blends grouped into chains; the 1-D nodes and the
   bodies between them with their limits;
4. speed profile (`plan_profile`): boundary speeds and the pieces of s(t), dwells included;
   with the jerk filter the chains' limits are then taken at what that profile does and it
   is planned again (`plan_relax`, a fixed point checked on the plan);
5. sampling (`plan_sampling`): s(t) at t = k * period, mapped onto the blended path.

The jerk profile plans s acceleration-limited (the raw plan) and averages it over a window
T = max a_max/j_max (`jerk_filter`, docs/planner.md): the stages give the raw plan what the
filter needs (sharp corners and stops hold their speed around the node, chains are cut at
every node with their limits eroded over a window), and sampling applies the filter exactly.

G60, G61, G9, dwells and stopping M-codes end a move at rest. After an exact stop (G60, G61,
G61.1, G9) the setpoint is held for `exact_stop_settle_s`, a dwell on the stopping block's line
before the next block's events: the fixed-time model of the NC's wait for the in-position
window. Profile pieces are trapezoids (acceleration-limited); the jerk profile filters them.

Look-ahead: a backward pass of braking bounds and a forward pass over the boundary speeds of up
to `lookahead_segments` moves, with the window's end at rest; the first half is committed,
sampled and yielded, the rest is planned again with the next moves (the moves the filter's
window still runs on stay listed as context, with their blends). Committed speeds stay
reachable as constraints relax (the braking bound is monotonic), so the result is always
safe, and memory stays bounded. Where the next moves tighten them instead (the blend at the
window's last node, where it stopped, lowers the limits of the bodies before it; a forced
break dropped later merges chains), the next window plans again with the committed window's
forced breaks, then with its stop at its end too: the limits the committed speed was planned
with, as a controller whose look-ahead ran short stops there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from enum import IntEnum
from pathlib import Path
from typing import NamedTuple

import numpy as np

from feed_twin.gcode.config import NcConfig
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.interpreter import Interpreter
from feed_twin.gcode.items import Event, Move, Stop
from feed_twin.gcode.jerk_filter import ROW_F, ROW_F_LO, ROW_S, ROW_T, two_sum
from feed_twin.gcode.lexer import Block, iter_source_lines, lex_line
from feed_twin.gcode.plan_blends import NodeFlags, WindowStart, corner_blends, fitted_widths
from feed_twin.gcode.plan_breaks import forced_breaks
from feed_twin.gcode.plan_chains import SINGLE, Bodies, StartHolds, chain_bodies
from feed_twin.gcode.plan_limits import AxisLimits, move_limits
from feed_twin.gcode.plan_profile import (
    motion_pieces,
    node_entries,
    speed_profile,
    speeds_fit,
    stop_holds,
    with_dwells,
)
from feed_twin.gcode.plan_relax import relaxed_plan
from feed_twin.gcode.plan_sampling import (
    END_SLACK,
    event_times,
    piece_starts,
    sample_filtered,
    sample_indices,
    sample_path,
)
from feed_twin.gcode.plan_smoothing import (
    SMOOTH_REACH,
    SMOOTH_SHARE,
    blend_tolerance,
    movable_vertices,
    smooth_vertices,
)
from feed_twin.gcode.trajectory import NcEvent, SampledTrajectory


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
    last = planner.plan(final=True)
    if last is not None:  # always: the final plan samples the rest, at least its end point
        yield last


class Kept(IntEnum):
    """What a window keeps of the previous window's decisions (`_StreamPlanner._as_decided`)."""

    NOTHING = 0
    BREAKS = 1  # its forced breaks
    BREAKS_AND_END = 2  # and its stops, the one at its end included


class _Decided(NamedTuple):
    """What a window that committed planned its nodes with (global node indices)."""

    end: int  # its last listed node (at rest there: the program's next moves were not listed)
    stop: np.ndarray  # the nodes it planned at rest
    forced: np.ndarray  # its forced breaks


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
        self.limits = AxisLimits.of(config)
        self.window_s = self.limits.window_s
        self.n_filter = self.limits.filter_n
        self.period = config.interpolation_period_s
        self.settle_s = config.exact_stop_settle_s
        self.forced = max(2, config.lookahead_segments // 4)  # spacing of forced breaks
        self.decided: dict[int, int] = {}  # global candidate -> its forced break (-1: none)
        # Listed moves: the not yet committed ones, preceded by one committed context move
        # (its end blend reaches into the next chunk) once anything was committed.
        self.points: list[tuple[float, ...]] = [config.start_position]
        self.lines: list[int] = []
        self.rapids: list[bool] = []
        self.arcs: list[bool] = []  # the move is a chord of an arc
        self.n_frozen = 1  # listed points that are final (smoothed and committed): the start
        self.feeds: list[float] = []
        self.tols: list[float] = []
        self.g0 = 0  # global index of listed move 0
        self.has_context = False
        self.w_context = np.zeros(1)  # blend half-widths of the listed nodes up to the first
        # Raw samples (s, ds/dt, F = integral of s dt, t, F's low part: jerk_filter.ROW_*)
        # within the jerk filter's span before the next one, in the listed moves' s (at first
        # the start point, at rest since t = 0); F at the end of the committed pieces, as the
        # sum of two doubles (jerk_filter.raw_samples says why).
        k_before = np.arange(1 - self.n_filter, 0)
        self.history = np.column_stack((0.0 * k_before, 0.0 * k_before, 0.0 * k_before,
                                        k_before * self.period, 0.0 * k_before))  # fmt: skip
        self.F_end = (0.0, 0.0)
        self.stops: set[int] = set()  # global node indices where the path is at rest
        self.entries: dict[int, list[Event | Stop]] = {}  # global node -> events and dwells
        self.v_first = 0.0
        self.first_stop = False  # whether the path stops there
        self.start_holds: StartHolds | None = None  # its holds, as committed (jerk filter)
        self.decided_before: _Decided | None = None  # the last committing window's decisions
        self.t_s = 0.0
        self.k_next = 0

    def first(self) -> int:
        """Listed moves kept as committed context before the first uncommitted node."""
        return len(self.w_context) - 1 if self.has_context else 0

    def pending_moves(self) -> int:
        return len(self.lines) - self.first()

    def add(self, item: Move | Stop | Event) -> None:
        node = self.g0 + len(self.lines)
        if isinstance(item, Move):
            self.points.append(item.end_m)
            self.lines.append(item.line)
            self.rapids.append(item.rapid)
            self.arcs.append(item.arc is not None)
            self.feeds.append(item.feed_m_s)
            self.tols.append(item.tolerance_m)
            if item.exact_stop:
                self.stops.add(node + 1)
                if self.settle_s > 0.0:
                    self.entries.setdefault(node + 1, []).append(Stop(item.line, self.settle_s))
            return
        self.entries.setdefault(node, []).append(item)
        if isinstance(item, Stop) or item.stops:
            self.stops.add(node)

    def plan(self, *, final: bool, as_decided: Kept = Kept.NOTHING) -> SampledTrajectory | None:
        """Plan the listed moves; sample and return what is committed (None: nothing yet).

        `as_decided`: what of the previous window's decisions on the nodes both list is kept
        (`_as_decided`); more is kept, step by step, where this window cannot keep v_first."""
        n = len(self.lines)
        if n == 0:
            return self._plan_standstill()
        first = self.first()
        listed = np.array(self.points)
        flags = self._node_flags(n, final, listed, as_decided)
        points, movable = self._smoothed(flags, listed)
        if np.any(movable):
            flags = dataclasses.replace(flags, tol=blend_tolerance(flags.tol, movable))
        moves = move_limits(points, self.rapids, self.feeds, self.limits)
        start = WindowStart(w=self.w_context, stop=self.first_stop) if self.has_context else None
        blends = corner_blends(moves, flags, self.limits, start)
        bodies = chain_bodies(
            moves,
            blends,
            flags,
            self.limits,
            first=first,
            open_end=not final,
            start_holds=self.start_holds if self.has_context else None,
        )
        if bodies is None:
            return self._plan_standstill() if final else None
        speeds = speed_profile(bodies, v_first=self.v_first, window_s=self.window_s)
        if (
            as_decided < Kept.BREAKS_AND_END
            and self.decided_before is not None
            and not speeds_fit(bodies, speeds.v)
        ):
            return self.plan(final=final, as_decided=Kept(as_decided + 1))
        q_commit = self._commit_point(bodies, movable, first, n, final)
        if q_commit is None:
            return None  # nothing safely committable yet: wait for more moves
        end_node = int(bodies.node[q_commit])
        w_limit = fitted_widths(
            blends, bodies.node, speeds.v, self.limits, extended=bodies.extended, last=end_node
        )
        if w_limit is not None:  # corners slower than their blends allow: narrower blends
            blends = corner_blends(moves, flags, self.limits, start, w_limit=w_limit)
            narrowed = chain_bodies(
                moves,
                blends,
                flags,
                self.limits,
                first=first,
                open_end=not final,
                holds_as=(bodies.extended, bodies.hold_in, bodies.hold_out),
            )
            assert narrowed is not None  # the same 1-D nodes: only widths changed
            bodies = narrowed
            speeds = speed_profile(bodies, v_first=self.v_first, window_s=self.window_s)
        bodies, speeds = relaxed_plan(
            bodies, speeds, self.limits, v_first=self.v_first, fixed_from=q_commit
        )
        pieces = motion_pieces(bodies, speeds, q_commit=q_commit, n_moves=n)
        dwells, timed = node_entries(self._entries_at(bodies, q_commit, final), bodies.S)
        holds = stop_holds(
            bodies,
            speeds,
            q_commit=q_commit,
            final=final,
            window_s=self.window_s,
            period=self.period,
        )
        pieces = with_dwells(pieces, holds + dwells)
        t0, t_end = piece_starts(pieces, self.t_s)
        events = event_times(timed, pieces, t0, t_end, q_commit)
        k_start, k_stop = sample_indices(self.k_next, t_end, self.period, final=final)
        times = np.arange(k_start, k_stop) * self.period
        if self.n_filter > 1:
            pos, vel, acc, piece, seg, self.history, self.F_end = sample_filtered(
                times,
                pieces,
                t0,
                moves,
                blends.w,
                blends.dU,
                history=self.history,
                F0=self.F_end,
                span=self.window_s,
            )
        else:
            pos, vel, acc, piece, seg = sample_path(times, pieces, t0, moves, blends.w, blends.dU)
        lines = np.array(self.lines, dtype=np.int64)[seg]
        held = pieces.line[piece]
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
        self.v_first = float(speeds.v[q_commit])
        self.start_holds = StartHolds(
            extended=bool(bodies.extended[q_commit]),
            hold_in=float(bodies.hold_in[q_commit]),
            hold_out=float(bodies.hold_out[q_commit]),
        )
        if not final:
            self.decided_before = _Decided(
                end=self.g0 + n,
                stop=self.g0 + np.flatnonzero(flags.stop),
                forced=self.g0 + np.flatnonzero(flags.forced),
            )
            self._drop_committed(end_node, bodies.S, blends.w, bool(blends.stop[end_node]), points)
        return chunk

    def _node_flags(self, n: int, final: bool, listed: np.ndarray, as_decided: Kept) -> NodeFlags:
        """Tolerances, stops, entries and forced breaks at the listed nodes 0..n; `as_decided`:
        those of the previous window where both list the node (`_as_decided`)."""
        g = self.g0
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
        tol = np.zeros(n + 1)
        tol[1:n] = self.tols[:-1]
        natural = stop | has_entries
        forced = forced_breaks(
            listed,
            natural,
            g0=g,
            spacing=self.forced,
            stable=n if final else n - (SMOOTH_REACH + 2),
            final=final,
            decided=self.decided,
            beyond=self._beyond_reach(listed) if final and self.has_context else None,
        )
        if not final:
            forced = self._commit_break_only(forced, listed, n)
        if as_decided > Kept.NOTHING:
            stop, forced = self._as_decided(stop, forced, n, end=as_decided == Kept.BREAKS_AND_END)
        return NodeFlags(tol=tol, stop=stop, has_entries=has_entries, forced=forced)

    def _as_decided(
        self, stop: np.ndarray, forced: np.ndarray, n: int, *, end: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """The forced breaks of the listed nodes after the first uncommitted one up to the
        previous window's last, as that window planned them (a break that `_commit_break_only`
        dropped since may merge chains and bring a sharper blend's curvature into them), and
        with `end` its stops: the one at its end too, where the program does not stop (its
        blend there may lower the limits of the bodies before it, `plan_chains._eroded`).

        With both this window plans those nodes on the same geometry and with the same limits
        as the window that committed v_first (its last body is even longer: the open end's
        share is gone), so v_first can brake to every constraint up to there; beyond the
        stop nothing reaches back. A controller whose look-ahead ran short stops there too."""
        decided = self.decided_before
        assert decided is not None
        g = self.g0
        nodes = np.arange(self.first() + 1, min(decided.end - g, n) + 1)
        stop = stop.copy()
        forced = forced.copy()
        if end:
            stop[nodes] |= np.isin(nodes + g, decided.stop)
        forced[nodes] = np.isin(nodes + g, decided.forced)
        return stop, forced

    def _commit_break_only(self, forced: np.ndarray, listed: np.ndarray, n: int) -> np.ndarray:
        """The forced breaks without those the window neither commits at nor leaves for a
        later window: of those from the first uncommitted node to the last one it may commit
        at, all but the last (the commit point, `_commit_point`) where beyond what the
        committed motion's filter windows reach. They lie in the committed part, where no
        later window plans again, and without them the constraints mostly relax (a break
        squeezes its neighbours' blends); where the chains a drop merges carry a sharper
        blend's curvature into bodies v_first must brake on, the next window keeps the break
        (`_as_decided`). Dropped for good (`decided`: none)."""
        first = self.first()
        top = min(self._commit_limit(n), n - max(3, SMOOTH_REACH + 1) - 1)
        at = np.flatnonzero(forced[first + 1 : top + 1])[:-1] + first + 1
        drop = at[self._beyond_reach(listed)[at]]
        if len(drop) == 0:
            return forced
        gone = {int(node) + self.g0 for node in drop}
        for key, node in self.decided.items():
            if node in gone:
                self.decided[key] = -1
        out = forced.copy()
        out[drop] = False
        return out

    def _commit_limit(self, n: int) -> int:
        """The last listed node a window of n moves may commit up to: about half the window;
        the forced breaks lie within an eighth of their spacing of every spacing-th node
        (`plan_breaks`), the last commit too: the one past half counts."""
        first = self.first()
        return first + (n - first) // 2 + self.forced // 4

    def _beyond_reach(self, listed: np.ndarray) -> np.ndarray:
        """Which listed nodes (n+1) lie beyond what the committed motion's filter windows and
        erosions reach from the first uncommitted node: 2 T times the highest speed a move
        between may run at (a rapid: the fastest any axis allows; a feed move its feed).
        The last window keeps the forced breaks up to there (`plan_breaks`)."""
        first = self.first()
        fastest = float(np.linalg.norm(self.limits.rapid))
        V = np.where(np.array(self.rapids[first:]), fastest, np.array(self.feeds[first:]))
        delta = np.diff(listed[first:], axis=0)
        S = np.cumsum(np.sqrt(np.einsum("ij,ij->i", delta, delta)))
        beyond = np.zeros(len(listed), dtype=bool)
        beyond[first + 1 :] = 2.0 * self.window_s * np.maximum.accumulate(V) < S
        return beyond

    def _smoothed(self, flags: NodeFlags, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The listed points with CAM polylines smoothed (jerk profile, `plan_smoothing`), and
        which of them moved; the frozen ones (committed) stay."""
        fixed = flags.stop | flags.has_entries | flags.forced
        fixed[: self.n_frozen] = True
        if self.window_s <= 0.0:
            return P, np.zeros(len(P), dtype=bool)
        movable = movable_vertices(P, np.array(self.rapids), np.array(self.arcs), fixed)
        if not np.any(movable):
            return P, movable
        limit = SMOOTH_SHARE * flags.tol
        return smooth_vertices(P, movable, limit, SMOOTH_REACH), movable

    def _commit_point(
        self, bodies: Bodies, movable: np.ndarray, first: int, n: int, final: bool
    ) -> int | None:
        """The 1-D node up to which the window is committed (None: none is safe yet).

        Up to a single corner well inside the window, so that the next window starting there
        sees the same geometry around it: a vertex that smoothing does not move, with the
        smoothing runs of the next vertex inside the window (`plan_smoothing`).
        """
        if final:
            return len(bodies.length)
        half = self._commit_limit(n)
        node_q, kind_q = bodies.node, bodies.kind
        margin = max(3, SMOOTH_REACH + 1) if np.any(movable) else 3
        candidates = np.flatnonzero(
            (kind_q[1:] == SINGLE)
            & (node_q[1:] <= half)
            & (node_q[1:] + margin < n)
            & ~movable[node_q[1:]]
        )
        if len(candidates) == 0:
            return None
        return int(candidates[-1]) + 1

    def _entries_at(
        self, bodies: Bodies, q_commit: int, final: bool
    ) -> list[tuple[int, int, list[Event | Stop]]]:
        """(slot, node, entries) of the committed single 1-D nodes with events or dwells."""
        nodes = bodies.node[: q_commit + 1]
        emit_nodes = list(nodes[:-1]) + ([nodes[-1]] if final else [])
        emit_kinds = list(bodies.kind[: len(emit_nodes)])
        out: list[tuple[int, int, list[Event | Stop]]] = []
        for slot, (j, kind_j) in enumerate(zip(emit_nodes, emit_kinds, strict=True)):
            entries = self.entries.pop(int(j) + self.g0, None) if kind_j == SINGLE else None
            if entries:
                out.append((slot, int(j), entries))
        return out

    def _drop_committed(
        self, end_node: int, S: np.ndarray, w: np.ndarray, stop_end: bool, points: np.ndarray
    ) -> None:
        """Forget the committed moves but the context: the move that ends at the commit node,
        and those the jerk filter's history still runs on (from the move before it). The
        points up to the one after the commit node, as planned (`points`), are frozen."""
        frozen = end_node + 2
        self.points[:frozen] = [tuple(p) for p in points[:frozen].tolist()]
        oldest = (
            int(np.searchsorted(S, float(self.history[0, 0]), side="right")) - 2
            if len(self.history)
            else end_node
        )
        keep = max(min(end_node - 1, oldest), 0)
        del self.points[:keep]
        del self.lines[:keep]
        del self.rapids[:keep]
        del self.arcs[:keep]
        del self.feeds[:keep]
        del self.tols[:keep]
        self.g0 += keep
        # s counted from the new first listed node: F = integral of s dt moves with it, by
        # S (t - t_s) (any constant more is as good: only F's differences count), whose terms
        # are small beside F over the span the history holds.
        h = self.history
        h[:, ROW_S] -= S[keep]
        h[:, ROW_F], err = two_sum(h[:, ROW_F], -S[keep] * (h[:, ROW_T] - self.t_s))
        h[:, ROW_F], h[:, ROW_F_LO] = two_sum(h[:, ROW_F], err + h[:, ROW_F_LO])
        self.n_frozen = frozen - keep
        self.has_context = True
        self.w_context = w[keep : end_node + 1].copy()
        self.first_stop = stop_end
        self.stops = {node for node in self.stops if node >= self.g0 + 1}
        self.decided = {node: at for node, at in self.decided.items() if max(node, at) >= self.g0}

    def _plan_standstill(self) -> SampledTrajectory:
        """A program (or tail) without moves: only dwells and events at the current point."""
        node = self.g0 + len(self.lines)
        entries = self.entries.pop(node, [])
        t = self.t_s
        events: list[NcEvent] = []
        spans: list[tuple[float, float, int]] = []
        for entry in entries:
            if isinstance(entry, Stop):
                spans.append((t, t + entry.dwell_s, entry.line))
                t += entry.dwell_s
            else:
                events.append(NcEvent(t, entry.line, entry.kind, entry.value, entry.text))
        k_stop = math.ceil(t / self.period - END_SLACK) + 1
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
