"""Lexer: one line of G-code text -> the words of that block, with their columns.

Accepts RS274/NGC (LinuxCNC), Fanuc- and Sinumerik-style text: case-insensitive, spaces
anywhere inside a word (`X - 1 .5` is not accepted, but `X -1.5` and `x-1.5` are), `( ... )`
and `; ...` comments, a leading `/` for block delete, `N` line numbers (dropped here) and `%`
delimiter lines. Controller-specific assignments and calls that do not move the axes
(Sinumerik `T="DRILL_10"`, `MSG("...")`, `R1=5`) come back as notes so the interpreter can
warn about them; a single axis letter assignment (`X=5`, Sinumerik) is an ordinary word.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

from feed_twin.gcode.errors import GcodeError

_TOKEN = re.compile(
    r"[ \t\r\f\v]+"
    r"|(?P<comment>\([^)]*\)|;.*)"
    r"|(?P<aname>[A-Za-z_][A-Za-z0-9_]*)[ \t]*=[ \t]*"
    r"(?P<avalue>\"[^\"]*\"|[-+]?[ \t]*(?:\d+\.?\d*|\.\d+)(?![\w.]))"
    r"|(?P<call>[A-Za-z_][A-Za-z0-9_]*)[ \t]*\([ \t]*\"[^\"]*\"[ \t]*\)"
    r"|(?P<letter>[A-Za-z])[ \t]*(?P<number>[-+]?[ \t]*(?:\d+\.?\d*|\.\d+))"
    r"|(?P<bad>.)"
)

# Most lines of CAM output are plain words; they take a faster route with the same result.
_SIMPLE_LINE = re.compile(r"(?:[ \t]*[A-Za-z][-+]?(?:\d+\.?\d*|\.\d+))+[ \t\r]*")
_SIMPLE_WORD = re.compile(r"([A-Za-z])([-+]?(?:\d+\.?\d*|\.\d+))")

_BAD_CHARACTER_REASONS = {
    "(": "comment '(' is never closed",
    "#": "parameters (#) are not supported",
    "[": "expressions [...] are not supported",
    "=": "assignment without a name",
    '"': "string outside an assignment",
}


class Word(NamedTuple):
    """One word of a block: `letter` upper case, `value` as written (program units)."""

    letter: str
    value: float
    column: int  # 1-based column of the letter
    text: str  # the word as written, spaces removed, letter upper case (for messages)


@dataclass(frozen=True, slots=True)
class Note:
    """A controller-specific item that does not move the axes (accepted with a warning)."""

    column: int
    text: str


class Block(NamedTuple):
    line: int  # 1-based line number in the file
    words: tuple[Word, ...]
    notes: tuple[Note, ...]


def lex_line(text: str, line: int, *, file: str, block_delete: bool) -> Block | None:
    """Split one line into words; None for lines without words (blank, comment, `%`, deleted)."""
    stripped = text.lstrip()
    if not stripped or stripped[0] == "%":
        return None
    start = 0
    if stripped[0] == "/":
        if block_delete:
            return None
        start = text.index("/") + 1
    if start == 0 and _SIMPLE_LINE.fullmatch(text):
        upper = text.upper()
        return Block(
            line,
            tuple(
                Word(m[1], float(m[2]), m.start() + 1, m[0]) for m in _SIMPLE_WORD.finditer(upper)
            ),
            (),
        )
    words: list[Word] = []
    notes: list[Note] = []
    for m in _TOKEN.finditer(text, start):
        kind = m.lastgroup
        if kind is None or kind == "comment":
            continue
        if kind == "number":
            number = m.group("number")
            if " " in number or "\t" in number:
                number = number.replace(" ", "").replace("\t", "")
            letter = m.group("letter").upper()
            words.append(Word(letter, float(number), m.start() + 1, letter + number))
        elif kind == "avalue":
            name = m.group("aname").upper()
            value = m.group("avalue")
            if (len(name) == 1 or name == "CR") and not value.startswith('"'):
                # Sinumerik: X=5 is X5, CR=10 is the circle radius (R10 elsewhere).
                number = value.replace(" ", "").replace("\t", "")
                letter = "R" if name == "CR" else name
                words.append(Word(letter, float(number), m.start() + 1, name + "=" + number))
            else:
                notes.append(Note(m.start() + 1, m.group(0)))
        elif kind == "call":
            notes.append(Note(m.start() + 1, m.group(0)))
        else:
            char = m.group("bad")
            column = m.start() + 1
            if char.isalpha():
                rest = text[m.end() :].lstrip()
                follower = rest[:1]
                if follower in ("#", "["):
                    word = char.upper() + rest.split()[0]
                    reason = _BAD_CHARACTER_REASONS[follower]
                else:
                    word, reason = char.upper(), "word has no number"
                raise GcodeError(reason, file=file, line=line, column=column, word=word)
            reason = _BAD_CHARACTER_REASONS.get(char, "unexpected character")
            raise GcodeError(reason, file=file, line=line, column=column, word=char)
    if not words and not notes:
        return None
    return Block(line, tuple(words), tuple(notes))


def iter_source_lines(source: str | Path) -> tuple[str, Iterator[tuple[int, str]]]:
    """(file name for messages, iterator of (line number, text)) for a path or program text.

    A `Path`, or a string that names an existing file, is read lazily line by line (bounded
    memory); a one-line string with a program file suffix (.ngc, .nc, .mpf, ...) that names no
    file is an error; any other string is the program text itself. Binary data raises a
    `GcodeError`.
    """
    # a caller may hand anything: the type checks below are for it, not for the annotation
    if isinstance(source, Path) or (
        isinstance(source, str)  # pyright: ignore[reportUnnecessaryIsInstance]
        and "\n" not in source
        and _is_file(source)
    ):
        path = Path(source)
        if not path.is_file():
            raise GcodeError("no such G-code file", file=str(path))
        return str(path), _file_lines(path)
    if not isinstance(source, str):  # pyright: ignore[reportUnnecessaryIsInstance]
        raise TypeError(f"expected a path or program text, got {type(source).__name__}")
    if "\n" not in source and Path(source).suffix.lower() in _PROGRAM_SUFFIXES:
        raise GcodeError("no such G-code file", file=source)
    return "<text>", _text_lines(source, "<text>")


# Longest program line read [bytes]: generous for hand-written and CAM lines, and it bounds the
# memory a line can take (a 10 MB line without breaks took 1.5 GB to lex).
MAX_LINE_BYTES = 4096

# A one-line string ending like this is a file name, never a program.
_PROGRAM_SUFFIXES = (".ngc", ".nc", ".gcode", ".cnc", ".tap", ".mpf", ".spf", ".iso", ".txt")


def _is_file(text: str) -> bool:
    try:
        return len(text) < 4096 and Path(text).is_file()
    except OSError:
        return False


def _check_text(text: str, number: int, file: str) -> None:
    if "\x00" in text:
        raise GcodeError(
            "not a text G-code file (NUL byte: binary data)",
            file=file,
            line=number,
            column=text.index("\x00") + 1,
        )


def _check_length(size: int, number: int, file: str) -> None:
    if size > MAX_LINE_BYTES:
        raise GcodeError(
            f"the line is longer than {MAX_LINE_BYTES} bytes (G-code lines are short: LinuxCNC "
            "reads at most 255 characters); a missing line break?",
            file=file,
            line=number,
        )


def _text_lines(text: str, file: str) -> Iterator[tuple[int, str]]:
    for number, line in enumerate(text.splitlines(), start=1):
        _check_length(len(line.encode("utf-8")), number, file)
        _check_text(line, number, file)
        yield number, line


def _file_lines(path: Path) -> Iterator[tuple[int, str]]:
    file = str(path)
    number = 0
    with path.open("rb") as handle:
        while raw := handle.readline(MAX_LINE_BYTES + 3):  # the line break may be \r\n
            number += 1
            _check_length(len(raw.rstrip(b"\r\n")), number, file)
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise GcodeError(
                    f"not a text G-code file (invalid UTF-8 byte 0x{raw[exc.start]:02x})",
                    file=file,
                    line=number,
                    column=exc.start + 1,
                ) from None
            _check_text(line, number, file)
            yield number, line.rstrip("\r\n")
