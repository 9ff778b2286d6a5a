# pyright: reportPrivateUsage=false
# (MODE_ACTIONS, the table of modal codes, names the interpreter's own _set_* methods)
"""Modal interpreter: blocks of words -> straight moves in machine coordinates (SI) and events.

The interpreter keeps the modal state of an RS274/NGC-style control (motion mode, plane,
units, absolute/incremental, arc-centre mode, work offset, G92 offset, path control, feed)
and turns each block into items for the planner:

- `Move`: a straight move to a machine position [m]. Arcs (G2/G3, I J K or R, full circles,
  helices, LinuxCNC `P` turns) become chords whose sagitta stays within the chord tolerance.
- `Stop`: the path stops at this point for `dwell_s` seconds (G4, and M-codes that a control
  executes at standstill: M0, M1, M2, M30, M3-M6).
- `Event`: something the recording shows (spindle, tool, coolant, pauses, warnings).

A block's words are first sorted and checked (`block_words.sort_words`: G-codes by name, at
most one per modal group, see `codes`); then they act in this order: units, F, S, T, M6, M3-M5,
M7-M9, G4, plane, distance modes, path control, work offset, motion mode, G92/G53 and the move,
then M0/M1/M2/M30. Modal codes set the state through `MODE_ACTIONS`, a table keyed by the
code's name. Units come before F (unlike RS274/NGC) so that `G20 F10` means 10 in/min, which is
what people who write it mean. Arc geometry lives in `arcs`.

Millimetres, inches and degrees exist only here: every number that leaves is SI (rotary axes
A, B, C in radians, after the linear axes).

Feed of moves with rotary axes (RS274/NGC, as LinuxCNC does it): when X, Y or Z move, F is the
speed along their path and the other axes arrive with them; otherwise when U, V or W move, the
same along theirs; a move of rotary axes alone runs at F degrees per minute along the rotary
path. Sinumerik's default (FGROUP(X, Y, Z)) is the same rule; an FGROUP that includes a rotary
axis is not modelled. The planner parameterises a move by the length over all its axes, so a
move's `feed_m_s` is that rule's duration expressed along that length.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator

from feed_twin.gcode.arcs import (
    ArcError,
    arc_sweep,
    centre_from_radius,
    check_centre,
    chord_points,
)
from feed_twin.gcode.block_words import BlockWords, sort_words
from feed_twin.gcode.codes import (
    ARC_DISTANCE,
    ARC_MOTIONS,
    CENTRE_LETTERS,
    DISTANCE,
    LINE_MOTIONS,
    M_COOLANT,
    M_PAUSES,
    M_SPINDLE,
    MM,
    MOTION,
    OTHER_LETTERS,
    PATH_CONTROL,
    PLANE,
    PLANE_AXES,
    PLANE_NAMES,
    UNIT_CODES,
    UNITS,
    WORK_OFFSET,
)
from feed_twin.gcode.config import NcConfig
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.items import Event, Item, Move, Stop
from feed_twin.gcode.lexer import Block, Word

DEG = math.pi / 180.0  # [rad] per degree
_LINE_MOTION_NAMES = {0.0: "G0", 1.0: "G1"}  # G word values the fast path of CAM blocks takes


class Interpreter:
    """Holds the modal state; `run(blocks)` yields items. One instance runs one program."""

    def __init__(self, config: NcConfig, *, file: str) -> None:
        self.config = config
        self.file = file
        self.axis_names = config.axis_names
        self.n_axes = len(self.axis_names)
        self.axis_letters = frozenset(self.axis_names)
        self.allowed = self.axis_letters | OTHER_LETTERS
        self.index = {name: i for i, name in enumerate(self.axis_names)}
        self.travel = list(config.travel)
        self.position = list(config.start_position)
        self.rotary = [config.axis_kind(name) == "rotary" for name in self.axis_names]
        self.n_linear = self.rotary.count(False)
        # RS274/NGC feed groups: XYZ, else UVW (else rotary): indices of each among the axes
        self.feed_groups = [
            [i for i, name in enumerate(self.axis_names) if name in group]
            for group in ("XYZ", "UVW", "ABC")
        ]
        self.motion: str | None = None  # G0, G1, G2, G3; None after G80
        self.plane = "G17"
        self.length_unit = MM
        self.feed_unit = MM
        self.absolute = True
        self.arc_absolute = False
        self.exact_stop_mode = False
        self.tolerance = config.path_tolerance_m
        self.work_offset = self._offset("G54")
        self.g92 = [0.0] * self.n_axes
        self.feed: float | None = None
        self.feed_per_min = 0.0  # the F word as written (units or degrees per minute)
        self.spindle_rpm = 0.0
        self.tool = 0.0
        self.ended = False
        self.moves = 0

    def error(self, reason: str, word: Word | None, line: int) -> GcodeError:
        if word is None:
            return GcodeError(reason, file=self.file, line=line)
        return GcodeError(reason, file=self.file, line=line, column=word.column, word=word.text)

    def run(self, blocks: Iterable[Block]) -> Iterator[Item]:
        for block in blocks:
            if self.ended:
                return
            yield from self.block(block)

    def block(self, block: Block) -> list[Item]:
        if not block.notes and self.motion in LINE_MOTIONS:
            simple = self._simple_block(block)
            if simple is not None:
                return simple
        line = block.line
        words = sort_words(block, allowed=self.allowed, file=self.file)
        out: list[Item] = [Event(line, "warning", 0.0, text, False) for text in words.notes]
        # Units come before F, so that `G20 F10` is 10 in/min.
        self._apply_modes(words, (UNITS,), line)
        self._feed_spindle_tool(words.other, out, line)
        stop_codes = self._m_codes(words.m_codes, out, line)
        g4 = words.non_modal.get("G4")
        if g4 is not None:
            out.extend(self._dwell(g4, words, line))
        path = words.modal.get(PATH_CONTROL)
        self._apply_modes(words, (PLANE, DISTANCE, ARC_DISTANCE, PATH_CONTROL, WORK_OFFSET), line)
        self._apply_modes(words, (MOTION,), line)
        axis_words = self._motion(words, out, line)
        self._check_leftovers(words, axis_words, line, dwell=g4 is not None, path=path is not None)
        for code, w in stop_codes:
            if code in M_PAUSES:
                out.append(Event(line, M_PAUSES[code], 0.0, f"M{code}", True))
            else:
                out.append(Event(line, "end", float(code), w.text, True))
                self.ended = True
        return out

    def _apply_modes(self, words: BlockWords, groups: tuple[str, ...], line: int) -> None:
        """Set the modal state of these groups from the block's codes (in this order)."""
        for group in groups:
            code = words.modal.get(group)
            if code is not None:
                MODE_ACTIONS[code[0]](self, code[0], words, line)

    def _set_units(self, name: str, words: BlockWords, line: int) -> None:
        length_unit, feed_unit = UNIT_CODES[name]
        self.length_unit = length_unit
        if feed_unit is not None:
            self.feed_unit = feed_unit

    def _set_plane(self, name: str, words: BlockWords, line: int) -> None:
        self.plane = name

    def _set_distance(self, name: str, words: BlockWords, line: int) -> None:
        self.absolute = name == "G90"

    def _set_arc_distance(self, name: str, words: BlockWords, line: int) -> None:
        self.arc_absolute = name == "G90.1"

    def _set_exact_stop(self, name: str, words: BlockWords, line: int) -> None:
        self.exact_stop_mode = True

    def _set_blending(self, name: str, words: BlockWords, line: int) -> None:
        """G64 [P tolerance] [Q tolerance]."""
        self.exact_stop_mode = False
        p_word = words.other.pop("P", None)
        if p_word is not None:
            if p_word.value <= 0.0:
                raise self.error("G64 P tolerance must be > 0", p_word, line)
            self.tolerance = p_word.value * self.length_unit
        else:
            self.tolerance = self.config.path_tolerance_m
        # LinuxCNC's naive-CAM tolerance: it may merge nearly collinear G1 moves into one
        # within Q. This planner follows every vertex, which that tolerance allows.
        q_word = words.other.pop("Q", None)
        if q_word is not None:
            if p_word is None:
                raise self.error("G64 Q needs a P tolerance in the same block", q_word, line)
            if q_word.value < 0.0:
                raise self.error("G64 Q tolerance must be >= 0", q_word, line)

    def _set_work_offset(self, name: str, words: BlockWords, line: int) -> None:
        self.work_offset = self._offset(name)

    def _set_motion(self, name: str, words: BlockWords, line: int) -> None:
        self.motion = None if name == "G80" else name

    def _feed_spindle_tool(self, other: dict[str, Word], out: list[Item], line: int) -> None:
        """F, S and T words: the feed, the spindle speed and the selected tool."""
        f_word = other.pop("F", None)
        if f_word is not None:
            if f_word.value <= 0.0:
                raise self.error("feed must be > 0", f_word, line)
            self.feed = f_word.value * self.feed_unit / 60.0
            self.feed_per_min = f_word.value
        s_word = other.pop("S", None)
        if s_word is not None:
            if s_word.value < 0.0:
                raise self.error("spindle speed must be >= 0", s_word, line)
            self.spindle_rpm = s_word.value
            out.append(Event(line, "spindle_speed", s_word.value, f"S{s_word.value:g}", False))
        t_word = other.pop("T", None)
        if t_word is not None:
            if t_word.value < 0.0 or t_word.value != round(t_word.value):
                raise self.error("tool number must be a whole number >= 0", t_word, line)
            self.tool = t_word.value
            out.append(Event(line, "tool_select", t_word.value, f"T{t_word.value:g}", False))

    def _m_codes(
        self, m_codes: list[tuple[int, Word]], out: list[Item], line: int
    ) -> list[tuple[int, Word]]:
        """Events of M6, M3-M5, M7-M9; returns the stopping ones (M0, M1, M2, M30) for later."""
        stop_codes: list[tuple[int, Word]] = []
        for code, w in m_codes:
            if code == 6:
                out.append(Event(line, "tool_change", self.tool, f"M6 T{self.tool:g}", True))
            elif code in M_SPINDLE:
                out.append(Event(line, M_SPINDLE[code], self.spindle_rpm, w.text, True))
            elif code == 5:
                out.append(Event(line, "spindle_stop", 0.0, w.text, True))
            elif code in M_COOLANT:
                value = 0.0 if M_COOLANT[code] == "coolant_off" else float(code)
                out.append(Event(line, M_COOLANT[code], value, w.text, False))
            else:
                stop_codes.append((code, w))
        return stop_codes

    def _motion(self, words: BlockWords, out: list[Item], line: int) -> dict[str, Word]:
        """G92 offsets, G53 and the move of the block; returns the axis words it moved by."""
        non_modal = words.non_modal
        motion = words.modal.get(MOTION)
        axis_words = {k: w for k, w in words.other.items() if k in self.axis_letters}
        g92 = non_modal.get("G92")
        g53 = non_modal.get("G53")
        if "G92.1" in non_modal or "G92.2" in non_modal:
            self.g92 = [0.0] * self.n_axes
        if g92 is not None:
            if not axis_words:
                raise self.error("G92 needs at least one axis word", g92, line)
            for letter, w in axis_words.items():
                i = self.index[letter]
                self.g92[i] = self.position[i] - self.work_offset[i] - w.value * self._unit(i)
            return {}
        if not axis_words:
            if g53 is not None:
                raise self.error("G53 without axis words", g53, line)
            return axis_words
        first_axis = min(axis_words.values(), key=lambda w: w.column)
        if self.motion is None:
            raise self.error("axis word without a motion mode (G0, G1, G2, G3)", first_axis, line)
        if g53 is not None:
            if self.motion not in LINE_MOTIONS:
                raise self.error("G53 needs G0 or G1", g53, line)
            if not self.absolute:
                raise self.error("G53 is not allowed in incremental mode (G91)", g53, line)
        blame = (
            motion[1] if motion is not None else min(axis_words.values(), key=lambda w: w.column)
        )
        target = self._target(axis_words, machine=g53 is not None, line=line)
        # a G1 to where the axes stand (a Sinumerik program's opening `G1 B0`) moves nothing
        # and needs no feed; an arc to its start point is a full circle and does
        stays = self.motion == "G1" and all(
            abs(a - b) <= 1e-12 for a, b in zip(target, self.position, strict=True)
        )
        if self.motion != "G0" and self.feed is None and not stays:
            raise self.error("feed move before any F word", blame, line)
        exact_stop = "G9" in non_modal
        if self.motion in LINE_MOTIONS:
            self._check_travel(target, axis_words, blame, line)
            out.extend(self._line_move(target, line, exact_stop=exact_stop))
        else:
            out.extend(self._arc(target, axis_words, words.other, blame, exact_stop, line))
        return axis_words

    def _check_leftovers(
        self, words: BlockWords, axis_words: dict[str, Word], line: int, *, dwell: bool, path: bool
    ) -> None:
        """Words that no code of the block used."""
        other = words.other
        arc_move = bool(axis_words) and self.motion in ARC_MOTIONS
        leftover = [w for k, w in other.items() if k in ("I", "J", "K", "R")]
        if leftover and not arc_move:
            raise self.error(
                "arc word without an arc move (G2, G3 with axis words)", leftover[0], line
            )
        q_left = other.get("Q")
        if q_left is not None:
            raise self.error("Q word without G64 P", q_left, line)
        p_left = other.get("P")
        if p_left is not None and not dwell and not path and not arc_move:
            raise self.error("P word without G4, G64 or an arc", p_left, line)

    def _simple_block(self, block: Block) -> list[Item] | None:
        """The common CAM block (axis words, maybe F and N) in G0/G1; None for anything else.

        Same result as the general path, which handles (and reports) everything else.
        """
        target = list(self.position)
        index = self.index
        seen: set[str] = set()
        feed = None
        motion = self.motion
        unit = self.length_unit
        absolute = self.absolute
        for w in block.words:
            letter = w.letter
            if letter in seen:
                return None
            seen.add(letter)
            i = index.get(letter)
            if i is not None:
                if i >= self.n_linear:
                    return None
                if absolute:
                    target[i] = w.value * unit + self.work_offset[i] + self.g92[i]
                else:
                    target[i] = self.position[i] + w.value * unit
            elif letter == "F":
                if w.value <= 0.0:
                    return None
                feed = w.value
            elif letter == "G" and w.value in _LINE_MOTION_NAMES:
                motion = _LINE_MOTION_NAMES[w.value]
            elif letter != "N":
                return None
        if len(seen) == ("N" in seen) + (feed is not None) + ("G" in seen):
            return None
        if motion == "G1" and self.feed is None and feed is None:
            return None
        for i, x in enumerate(target):
            low, high = self.travel[i]
            if not low - 1e-12 <= x <= high + 1e-12:
                return None
        if feed is not None:
            self.feed = feed * self.feed_unit / 60.0
            self.feed_per_min = feed
        self.motion = motion
        return self._line_move(target, block.line, exact_stop=False)

    def _dwell(self, g4: Word, words: BlockWords, line: int) -> list[Item]:
        other = words.other
        if MOTION in words.modal:
            raise self.error("G4 cannot share a block with a motion code", g4, line)
        p_word = other.pop("P", None)
        if p_word is not None:
            seconds = p_word.value * (1e-3 if self.config.dwell_p_unit == "ms" else 1.0)
            source = p_word
        else:
            x_word = other.pop("X", None)
            if x_word is None:
                raise self.error("G4 dwell needs a P (or X) word with the time", g4, line)
            seconds = x_word.value
            source = x_word
        if seconds < 0.0:
            raise self.error("dwell time must be >= 0", source, line)
        return [
            Event(line, "dwell", seconds, f"G4 {source.text}", True),
            Stop(line, seconds),
        ]

    def _target(self, axis_words: dict[str, Word], *, machine: bool, line: int) -> list[float]:
        target = list(self.position)
        for letter, w in axis_words.items():
            i = self.index[letter]
            value = w.value * self._unit(i)
            if machine:
                target[i] = value
            elif self.absolute:
                target[i] = value + self.work_offset[i] + self.g92[i]
            else:
                target[i] = self.position[i] + value
        return target

    def _check_travel(
        self, point: list[float], axis_words: dict[str, Word], blame: Word, line: int
    ) -> None:
        for i, x in enumerate(point):
            low, high = self.travel[i]
            if not low - 1e-12 <= x <= high + 1e-12:
                name = self.axis_names[i]
                unit, text = (DEG, "deg") if self.rotary[i] else (MM, "mm")
                raise self.error(
                    f"{name} = {x / unit:.6g} {text} (machine) is outside the travel "
                    f"[{low / unit:.6g}, {high / unit:.6g}] {text}",
                    axis_words.get(name, blame),
                    line,
                )

    def _line_move(self, target: list[float], line: int, *, exact_stop: bool) -> list[Item]:
        for a, b in zip(target, self.position, strict=True):
            if abs(a - b) > 1e-12:
                break
        else:
            return []
        start = self.position
        self.position = target
        rapid = self.motion == "G0"
        return [
            Move(
                line,
                tuple(target),
                rapid,
                0.0 if rapid else self._path_feed(start, target),
                self.tolerance,
                self.exact_stop_mode or exact_stop,
            )
        ]

    def _arc(
        self,
        target: list[float],
        axis_words: dict[str, Word],
        other: dict[str, Word],
        blame: Word,
        exact_stop: bool,
        line: int,
    ) -> list[Item]:
        first, second, normal, c1_letter, c2_letter = PLANE_AXES[self.plane]
        i1, i2, i_n = self.index[first], self.index[second], self.index[normal]
        start = self.position
        start_ab, end_ab = (start[i1], start[i2]), (target[i1], target[i2])
        centre_words = {k: other[k] for k in CENTRE_LETTERS if k in other}
        r_word = other.get("R")
        for k, w in centre_words.items():
            if k not in (c1_letter, c2_letter):
                raise self.error(
                    f"not an arc-centre word in the {PLANE_NAMES[self.plane]} plane", w, line
                )
        if r_word is not None and centre_words:
            raise self.error("arc with both R and I/J/K", r_word, line)
        clockwise = self.motion == "G2"
        p_word = other.get("P")
        turns = 1
        if p_word is not None:
            turns = round(p_word.value)
            if turns < 1 or turns != p_word.value:
                raise self.error("arc turn count P must be a whole number >= 1", p_word, line)
        tol = self.config.arc_radius_tolerance_m
        if r_word is not None:
            radius = r_word.value * self.length_unit
            try:
                centre = centre_from_radius(start_ab, end_ab, radius, clockwise=clockwise, tol=tol)
            except ArcError as e:
                raise self.error(str(e), r_word, line) from None
        else:
            if not centre_words:
                raise self.error("arc without a centre (I/J/K) or radius (R)", blame, line)
            off1 = centre_words.get(c1_letter)
            off2 = centre_words.get(c2_letter)
            centre = self._centre_from_offsets(start_ab, (i1, i2), off1, off2)
            try:
                check_centre(start_ab, end_ab, centre, tol)
            except ArcError as e:
                raise self.error(str(e), off1 or off2, line) from None
        arc = arc_sweep(
            start_ab,
            end_ab,
            centre,
            (i1, i2, i_n),
            clockwise=clockwise,
            turns=turns,
            full_circle_if_closed=r_word is None,
            tol=tol,
        )
        exact_end = self.exact_stop_mode or exact_stop
        points = chord_points(start, target, arc, self.config.chord_tolerance_m)
        items: list[Item] = []
        previous = start
        for k, point in enumerate(points, start=1):
            last = k == len(points)
            self._check_travel(point, axis_words if last else {}, blame, line)
            feed = self._path_feed(previous, point)
            previous = point
            items.append(
                Move(line, tuple(point), False, feed, self.tolerance, exact_end and last, arc)
            )
        self.position = list(target)
        return items

    def _centre_from_offsets(
        self,
        start: tuple[float, float],
        axes: tuple[int, int],
        off1: Word | None,
        off2: Word | None,
    ) -> tuple[float, float]:
        """The centre of an I/J/K arc: from the start point (G91.1) or work coordinates (G90.1)."""
        i1, i2 = axes
        unit = self.length_unit
        a0, b0 = start
        v1 = off1.value * unit if off1 is not None else 0.0
        v2 = off2.value * unit if off2 is not None else 0.0
        if self.arc_absolute:
            ca = v1 + self.work_offset[i1] + self.g92[i1] if off1 is not None else a0
            cb = v2 + self.work_offset[i2] + self.g92[i2] if off2 is not None else b0
            return ca, cb
        return a0 + v1, b0 + v2

    def _unit(self, i: int) -> float:
        """SI value of one unit of axis i's word: degrees for rotary axes, else mm or inch."""
        return DEG if self.rotary[i] else self.length_unit

    def _offset(self, code: str) -> list[float]:
        """The work offset of G54-G59 for every axis (rotary axes: none)."""
        linear = list(getattr(self.config.work_offsets_m, code))
        return linear + [0.0] * (self.n_axes - len(linear))

    def _path_feed(self, start: list[float], end: list[float]) -> float:
        """The feed along the move's length over all axes under the RS274/NGC rule: F along
        the first feed group that moves (XYZ, UVW), rotary axes in step; rotary-only: deg/min."""
        total2 = sum((b - a) ** 2 for a, b in zip(start, end, strict=True))
        for group, feed in zip(self.feed_groups, (self.feed, self.feed, None), strict=True):
            moved2 = sum((end[i] - start[i]) ** 2 for i in group)
            if moved2 > 0.0:
                if feed is None:  # rotary axes alone: F in degrees per minute
                    return self.feed_per_min * DEG / 60.0
                return feed * math.sqrt(total2 / moved2)
        # no axis moved: callers drop such moves (and check for an F word first)
        return self.feed if self.feed is not None else 0.0


# The modal codes that change the interpreter's state, and how (groups not listed here, such
# as feed mode G94, cutter compensation G40 and tool length offset G43/G49, change nothing)
MODE_ACTIONS: dict[str, Callable[[Interpreter, str, BlockWords, int], None]] = {
    **dict.fromkeys(UNIT_CODES, Interpreter._set_units),
    **dict.fromkeys(PLANE_AXES, Interpreter._set_plane),
    **dict.fromkeys(("G90", "G91"), Interpreter._set_distance),
    **dict.fromkeys(("G90.1", "G91.1"), Interpreter._set_arc_distance),
    **dict.fromkeys(("G60", "G61", "G61.1"), Interpreter._set_exact_stop),
    "G64": Interpreter._set_blending,
    **dict.fromkeys(("G54", "G55", "G56", "G57", "G58", "G59"), Interpreter._set_work_offset),
    **dict.fromkeys(("G0", "G1", "G2", "G3", "G80"), Interpreter._set_motion),
}
