"""Modal interpreter: blocks of words -> straight moves in machine coordinates (SI) and events.

The interpreter keeps the modal state of an RS274/NGC-style control (motion mode, plane,
units, absolute/incremental, arc-centre mode, work offset, G92 offset, path control, feed)
and turns each block into items for the planner:

- `Move`: a straight move to a machine position [m]. Arcs (G2/G3, I J K or R, full circles,
  helices, LinuxCNC `P` turns) become chords whose sagitta stays within the chord tolerance.
- `Stop`: the path stops at this point for `dwell_s` seconds (G4, and M-codes that a control
  executes at standstill: M0, M1, M2, M30, M3-M6).
- `Event`: something the recording shows (spindle, tool, coolant, pauses, warnings).

Within a block the words act in this order: units, F, S, T, M6, M3-M5, M7-M9, G4, plane, modes,
work offset, G92/G53, motion, then M0/M1/M2/M30. Units come before F (unlike RS274/NGC) so
that `G20 F10` means 10 in/min, which is what people who write it mean.

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
from collections.abc import Iterable, Iterator
from typing import NamedTuple

from feed_twin.gcode.config import NcConfig
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.lexer import Block, Word

MM = 1e-3  # [m] per millimetre
DEG = math.pi / 180.0  # [rad] per degree
INCH = 25.4e-3  # [m] per inch
CHORD_SAGITTA_SHARE = 0.75  # largest chord sagitta, as a share of the chord tolerance


class Arc(NamedTuple):
    """The programmed circle (or helix) of a G2/G3 block, shared by all of its chords.

    At the fraction f of the sweep the point is centre + r(f) (cos, sin)(theta0 + f sweep) in
    the plane, r(f) = r_start + (r_end - r_start) f; every other axis moves linearly in f.
    """

    plane_axes: tuple[int, int, int]  # axis indices: first, second and normal axis of the plane
    centre_m: tuple[float, float]  # [m] centre in machine coordinates (first, second axis)
    r_start_m: float  # [m] radius at the start point
    r_end_m: float  # [m] radius at the end point (differs within arc_radius_tolerance_m)
    theta0_rad: float  # [rad] angle of the start point, from the first axis towards the second
    sweep_rad: float  # [rad] signed sweep, > 0 counter-clockwise (G3), full turns included


class Move(NamedTuple):
    line: int
    end_m: tuple[float, ...]  # [m] machine coordinates, one per configured axis
    rapid: bool  # G0: per-axis rapid rates; otherwise the programmed feed
    feed_m_s: float  # programmed feed (0 for rapids) along the move's length over all axes
    # (m and rad): the F of XYZ moves; see the module's note on rotary axes
    tolerance_m: float  # [m] allowed corner deviation at the end of this move (G64)
    exact_stop: bool  # stop at the end of this move (G61, G9)
    arc: Arc | None = None  # the programmed arc this move is a chord of


class Stop(NamedTuple):
    line: int
    dwell_s: float  # [s] time spent at standstill


class Event(NamedTuple):
    line: int
    kind: str
    value: float
    text: str
    stops: bool  # the path comes to rest before the event happens


Item = Move | Stop | Event

# Known G-codes with modal group, as tenths (G90.1 -> 901), so that lookup is an int compare.
_MOTION = {0: 0, 10: 1, 20: 2, 30: 3, 800: None}
_PLANE = {170: 17, 180: 18, 190: 19}
_UNITS = {
    200: "inch",
    210: "mm",
    700: "inch_geometry",
    710: "mm_geometry",
    7000: "inch",
    7100: "mm",
}
_GROUP_OF: dict[int, str] = {}
for _code in _MOTION:
    _GROUP_OF[_code] = "motion"
for _code in _PLANE:
    _GROUP_OF[_code] = "plane"
for _code in _UNITS:
    _GROUP_OF[_code] = "units"
_GROUP_OF.update({900: "distance", 910: "distance", 901: "arc distance", 911: "arc distance"})
_GROUP_OF.update({940: "feed mode", 610: "path control", 611: "path control", 640: "path control"})
_GROUP_OF.update({c: "work offset" for c in (540, 550, 560, 570, 580, 590)})
_GROUP_OF.update({40: "non-modal", 90: "non-modal", 530: "non-modal", 920: "non-modal"})
_GROUP_OF.update({921: "non-modal", 922: "non-modal"})
_GROUP_OF.update({400: "cutter compensation", 430: "tool length offset", 490: "tool length offset"})
_UNSUPPORTED_G = {
    930: "unsupported mode (inverse-time feed)",
    950: "unsupported mode (feed per revolution)",
    960: "unsupported mode (constant surface speed)",
    410: "unsupported mode (cutter radius compensation)",
    420: "unsupported mode (cutter radius compensation)",
    280: "unsupported (return to reference point)",
    300: "unsupported (return to reference point)",
    100: "unsupported (setting offsets from the program)",
    50: "unsupported (spline motion)",
    51: "unsupported (spline motion)",
    923: "unsupported (restoring G92 offsets)",
}
_UNSUPPORTED_G.update({c: "unsupported (canned cycle)" for c in range(810, 900, 10)})
_UNSUPPORTED_G.update({c: "unsupported (canned cycle)" for c in (730, 740, 760)})
_UNSUPPORTED_G.update({c: "unsupported (probing)" for c in (382, 383, 384, 385)})
_UNSUPPORTED_G.update({c: "unsupported (spindle-synchronised motion)" for c in (330, 331, 760)})

_M_KNOWN = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 30}
_CENTRE_LETTERS = ("I", "J", "K")
_OTHER_LETTERS = frozenset("FSTIJKRPQ")
# Plane -> (first axis, second axis, normal axis, first centre letter, second centre letter)
_PLANE_AXES = {
    17: ("X", "Y", "Z", "I", "J"),
    18: ("Z", "X", "Y", "K", "I"),
    19: ("Y", "Z", "X", "J", "K"),
}
_PLANE_NAMES = {17: "G17 (XY)", 18: "G18 (ZX)", 19: "G19 (YZ)"}


class Interpreter:
    """Holds the modal state; `run(blocks)` yields items. One instance runs one program."""

    def __init__(self, config: NcConfig, *, file: str) -> None:
        self.config = config
        self.file = file
        self.axis_names = config.axis_names
        self.n_axes = len(self.axis_names)
        self.axis_letters = frozenset(self.axis_names)
        self.allowed = self.axis_letters | _OTHER_LETTERS
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
        self.motion: int | None = None
        self.plane = 17
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
        if not block.notes and self.motion in (0, 1):
            simple = self._simple_block(block)
            if simple is not None:
                return simple
        line = block.line
        out: list[Item] = []
        g_words: dict[str, tuple[int, Word]] = {}
        m_words: list[tuple[int, Word]] = []
        other: dict[str, Word] = {}
        notes = [
            f"line {line}: controller-specific word {note.text} ignored" for note in block.notes
        ]
        for w in block.words:
            letter = w.letter
            if letter == "G":
                code = round(w.value * 10)
                if abs(w.value * 10 - code) > 1e-6:
                    raise self.error("unknown G-code", w, line)
                if code in _UNSUPPORTED_G:
                    raise self.error(_UNSUPPORTED_G[code], w, line)
                group = _GROUP_OF.get(code)
                if group is None:
                    raise self.error("unknown G-code", w, line)
                if group in g_words and group != "non-modal":
                    first = g_words[group][1]
                    raise self.error(
                        f"conflicts with {first.text} (both in the {group} group)", w, line
                    )
                if group == "non-modal":
                    g_words[f"non-modal {code}"] = (code, w)
                else:
                    g_words[group] = (code, w)
            elif letter == "M":
                code = round(w.value)
                if abs(w.value - code) > 1e-9 or code not in _M_KNOWN:
                    raise self.error("unsupported M-code", w, line)
                m_words.append((code, w))
            elif letter == "N":
                continue
            elif letter in ("D", "H"):
                notes.append(f"line {line}: {w.text} ignored (tool offsets are not modelled)")
            elif letter == "O" and len(block.words) == 1:
                notes.append(f"line {line}: program number {w.text} ignored")
            elif letter in self.allowed:
                if letter in other:
                    raise self.error(f"repeats {other[letter].text} in the same block", w, line)
                other[letter] = w
            else:
                if letter in ("A", "B", "C", "U", "V", "W"):
                    reason = f"unknown word (axis {letter} is not configured)"
                elif letter == "O":
                    reason = "unknown word (O-word subroutines are not supported)"
                else:
                    reason = "unknown word"
                raise self.error(reason, w, line)

        tool_length = g_words.get("tool length offset")
        if tool_length is not None and tool_length[0] == 430:
            notes.append(
                f"line {line}: {tool_length[1].text} tool length taken as 0 (no tool table)"
            )
        for text in notes:
            out.append(Event(line, "warning", 0.0, text, False))

        units = g_words.get("units")
        if units is not None:
            kind = _UNITS[units[0]]
            if kind == "inch":
                self.length_unit = self.feed_unit = INCH
            elif kind == "mm":
                self.length_unit = self.feed_unit = MM
            elif kind == "inch_geometry":
                self.length_unit = INCH
            else:
                self.length_unit = MM

        dwell_word = g_words.get("non-modal 40")
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
        stop_codes = []
        for code, w in m_words:
            if code == 6:
                out.append(Event(line, "tool_change", self.tool, f"M6 T{self.tool:g}", True))
            elif code in (3, 4):
                kind = "spindle_cw" if code == 3 else "spindle_ccw"
                out.append(Event(line, kind, self.spindle_rpm, w.text, True))
            elif code == 5:
                out.append(Event(line, "spindle_stop", 0.0, w.text, True))
            elif code in (7, 8):
                out.append(Event(line, "coolant_on", float(code), w.text, False))
            elif code == 9:
                out.append(Event(line, "coolant_off", 0.0, w.text, False))
            else:
                stop_codes.append((code, w))

        if dwell_word is not None:
            out.extend(self._dwell(dwell_word[1], other, g_words, line))

        plane = g_words.get("plane")
        if plane is not None:
            self.plane = _PLANE[plane[0]]
        distance = g_words.get("distance")
        if distance is not None:
            self.absolute = distance[0] == 900
        arc_distance = g_words.get("arc distance")
        if arc_distance is not None:
            self.arc_absolute = arc_distance[0] == 901
        path = g_words.get("path control")
        if path is not None:
            self.exact_stop_mode = path[0] != 640
            if path[0] == 640:
                p_word = other.pop("P", None)
                if p_word is not None:
                    if p_word.value <= 0.0:
                        raise self.error("G64 P tolerance must be > 0", p_word, line)
                    self.tolerance = p_word.value * self.length_unit
                else:
                    self.tolerance = self.config.path_tolerance_m
                # LinuxCNC's naive-CAM tolerance: it may merge nearly collinear G1 moves into one
                # within Q. This planner follows every vertex, which that tolerance allows.
                q_word = other.pop("Q", None)
                if q_word is not None:
                    if p_word is None:
                        raise self.error(
                            "G64 Q needs a P tolerance in the same block", q_word, line
                        )
                    if q_word.value < 0.0:
                        raise self.error("G64 Q tolerance must be >= 0", q_word, line)
        wcs = g_words.get("work offset")
        if wcs is not None:
            self.work_offset = self._offset(f"G{wcs[0] // 10}")

        motion = g_words.get("motion")
        if motion is not None:
            self.motion = _MOTION[motion[0]]
        motion_word = motion[1] if motion is not None else None
        axis_words = {k: w for k, w in other.items() if k in self.axis_letters}
        g92 = g_words.get("non-modal 920")
        g53 = g_words.get("non-modal 530")
        for reset in ("non-modal 921", "non-modal 922"):
            if reset in g_words:
                self.g92 = [0.0] * self.n_axes
        if g92 is not None:
            if not axis_words:
                raise self.error("G92 needs at least one axis word", g92[1], line)
            for letter, w in axis_words.items():
                i = self.index[letter]
                self.g92[i] = self.position[i] - self.work_offset[i] - w.value * self._unit(i)
            axis_words = {}
        elif axis_words:
            if self.motion is None:
                first = min(axis_words.values(), key=lambda w: w.column)
                raise self.error("axis word without a motion mode (G0, G1, G2, G3)", first, line)
            if g53 is not None:
                if self.motion not in (0, 1):
                    raise self.error("G53 needs G0 or G1", g53[1], line)
                if not self.absolute:
                    raise self.error("G53 is not allowed in incremental mode (G91)", g53[1], line)
            blame = motion_word or min(axis_words.values(), key=lambda w: w.column)
            target = self._target(axis_words, machine=g53 is not None, line=line)
            # a G1 to where the axes stand (a Sinumerik program's opening `G1 B0`) moves nothing
            # and needs no feed; an arc to its start point is a full circle and does
            stays = self.motion == 1 and all(
                abs(a - b) <= 1e-12 for a, b in zip(target, self.position, strict=True)
            )
            if self.motion != 0 and self.feed is None and not stays:
                raise self.error("feed move before any F word", blame, line)
            if self.motion in (0, 1):
                self._check_travel(target, axis_words, blame, line)
                out.extend(self._line_move(target, line, g_words))
            else:
                out.extend(self._arc(target, axis_words, other, blame, g_words, line))
        elif g53 is not None:
            raise self.error("G53 without axis words", g53[1], line)
        leftover = [w for k, w in other.items() if k in ("I", "J", "K", "R")]
        if leftover and not (axis_words and self.motion in (2, 3)):
            raise self.error(
                "arc word without an arc move (G2, G3 with axis words)", leftover[0], line
            )
        q_left = other.get("Q")
        if q_left is not None:
            raise self.error("Q word without G64 P", q_left, line)
        p_left = other.get("P")
        if (
            p_left is not None
            and dwell_word is None
            and path is None
            and not (axis_words and self.motion in (2, 3))
        ):
            raise self.error("P word without G4, G64 or an arc", p_left, line)

        for code, w in stop_codes:
            if code == 0:
                out.append(Event(line, "pause", 0.0, "M0", True))
            elif code == 1:
                out.append(Event(line, "optional_pause", 0.0, "M1", True))
            else:
                out.append(Event(line, "end", float(code), w.text, True))
                self.ended = True
        return out

    def _simple_block(self, block: Block) -> list[Item] | None:
        """The common CAM block (axis words, maybe F and N) in G0/G1; None for anything else.

        Same result as the general path, which handles (and reports) everything else.
        """
        target = list(self.position)
        index = self.index
        seen = set()
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
            elif letter == "G" and (w.value == 0.0 or w.value == 1.0):
                motion = int(w.value)
            elif letter != "N":
                return None
        if len(seen) == ("N" in seen) + (feed is not None) + ("G" in seen):
            return None
        if motion == 1 and self.feed is None and feed is None:
            return None
        for i, x in enumerate(target):
            low, high = self.travel[i]
            if not low - 1e-12 <= x <= high + 1e-12:
                return None
        if feed is not None:
            self.feed = feed * self.feed_unit / 60.0
            self.feed_per_min = feed
        self.motion = motion
        return self._line_move(target, block.line, {})

    def _dwell(self, g4: Word, other: dict[str, Word], g_words: dict, line: int) -> list[Item]:
        if "motion" in g_words:
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

    def _line_move(self, target: list[float], line: int, g_words: dict) -> list[Item]:
        for a, b in zip(target, self.position, strict=True):
            if abs(a - b) > 1e-12:
                break
        else:
            return []
        start = self.position
        self.position = target
        rapid = self.motion == 0
        return [
            Move(
                line,
                tuple(target),
                rapid,
                0.0 if rapid else self._path_feed(start, target),
                self.tolerance,
                self.exact_stop_mode or "non-modal 90" in g_words,
            )
        ]

    def _arc(
        self,
        target: list[float],
        axis_words: dict[str, Word],
        other: dict[str, Word],
        blame: Word,
        g_words: dict,
        line: int,
    ) -> list[Item]:
        first, second, normal, c1_letter, c2_letter = _PLANE_AXES[self.plane]
        i1, i2, i_n = self.index[first], self.index[second], self.index[normal]
        unit = self.length_unit
        start = self.position
        a0, b0 = start[i1], start[i2]
        a1, b1 = target[i1], target[i2]
        centre_words = {k: other[k] for k in _CENTRE_LETTERS if k in other}
        r_word = other.get("R")
        for k, w in centre_words.items():
            if k not in (c1_letter, c2_letter):
                raise self.error(
                    f"not an arc-centre word in the {_PLANE_NAMES[self.plane]} plane", w, line
                )
        if r_word is not None and centre_words:
            raise self.error("arc with both R and I/J/K", r_word, line)
        clockwise = self.motion == 2
        p_word = other.get("P")
        turns = 1
        if p_word is not None:
            turns = round(p_word.value)
            if turns < 1 or turns != p_word.value:
                raise self.error("arc turn count P must be a whole number >= 1", p_word, line)
        chord = math.hypot(a1 - a0, b1 - b0)
        tol = self.config.arc_radius_tolerance_m
        if r_word is not None:
            radius = r_word.value * unit
            if chord <= tol:
                raise self.error(
                    "R-form arc with equal start and end point (a full circle needs I/J/K)",
                    r_word,
                    line,
                )
            half = 0.5 * chord
            if abs(radius) < half - tol:
                raise self.error(
                    f"radius {abs(radius) / MM:.6g} mm is smaller than half the distance "
                    f"between start and end ({half / MM:.6g} mm)",
                    r_word,
                    line,
                )
            h = math.sqrt(max(radius * radius - half * half, 0.0))
            # The centre lies left of the chord for a short CCW arc; R < 0 asks for the long arc.
            side = (1.0 if not clockwise else -1.0) * (1.0 if radius > 0 else -1.0)
            ma, mb = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
            ca = ma - side * h * (b1 - b0) / chord
            cb = mb + side * h * (a1 - a0) / chord
        else:
            if not centre_words:
                raise self.error("arc without a centre (I/J/K) or radius (R)", blame, line)
            off1 = centre_words.get(c1_letter)
            off2 = centre_words.get(c2_letter)
            v1 = off1.value * unit if off1 is not None else 0.0
            v2 = off2.value * unit if off2 is not None else 0.0
            if self.arc_absolute:
                ca = v1 + self.work_offset[i1] + self.g92[i1] if off1 is not None else a0
                cb = v2 + self.work_offset[i2] + self.g92[i2] if off2 is not None else b0
            else:
                ca, cb = a0 + v1, b0 + v2
            r0 = math.hypot(a0 - ca, b0 - cb)
            r1 = math.hypot(a1 - ca, b1 - cb)
            culprit = off1 or off2
            if r0 <= tol:
                raise self.error("arc centre coincides with the start point", culprit, line)
            if abs(r0 - r1) > tol:
                raise self.error(
                    f"start radius {r0 / MM:.6g} mm and end radius {r1 / MM:.6g} mm differ by "
                    f"{abs(r0 - r1) / MM:.3g} mm (tolerance {tol / MM:.3g} mm)",
                    culprit,
                    line,
                )
        r0 = math.hypot(a0 - ca, b0 - cb)
        r1 = math.hypot(a1 - ca, b1 - cb)
        theta0 = math.atan2(b0 - cb, a0 - ca)
        theta1 = math.atan2(b1 - cb, a1 - ca)
        if clockwise:
            sweep = -((theta0 - theta1) % (2.0 * math.pi))
        else:
            sweep = (theta1 - theta0) % (2.0 * math.pi)
        if chord <= tol and r_word is None or sweep == 0.0:
            sweep = -2.0 * math.pi if clockwise else 2.0 * math.pi
        sweep += math.copysign(2.0 * math.pi * (turns - 1), sweep)
        radius = max(r0, r1)
        # The planner's chained blends round each chord vertex inwards by up to 4/3 of the
        # sagitta (|dU| w/6 with w up to a chord length: (2/3)(1 + cos(step/4)) sagittas), so
        # the chords keep 3/4 of the tolerance and the blended path stays within all of it.
        eps = CHORD_SAGITTA_SHARE * self.config.chord_tolerance_m
        step = 2.0 * math.acos(1.0 - eps / radius) if eps < radius else math.pi / 2
        n = max(1, math.ceil(abs(sweep) / min(step, math.pi / 2)))
        n0 = start[i_n]
        n1 = target[i_n]
        exact_end = self.exact_stop_mode or "non-modal 90" in g_words
        arc = Arc((i1, i2, i_n), (ca, cb), r0, r1, theta0, sweep)
        items: list[Item] = []
        previous = start
        for k in range(1, n + 1):
            if k == n:
                point = list(target)
            else:
                f = k / n
                theta = theta0 + sweep * f
                r = r0 + (r1 - r0) * f
                point = list(target)
                point[i1] = ca + r * math.cos(theta)
                point[i2] = cb + r * math.sin(theta)
                point[i_n] = n0 + (n1 - n0) * f
                for j in range(self.n_axes):
                    if j not in (i1, i2, i_n):
                        point[j] = start[j] + (target[j] - start[j]) * f
            self._check_travel(point, axis_words if k == n else {}, blame, line)
            feed = self._path_feed(previous, point)
            previous = point
            items.append(
                Move(line, tuple(point), False, feed, self.tolerance, exact_end and k == n, arc)
            )
        self.position = list(target)
        return items

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
        return self.feed
