"""A block's words sorted by role and checked: G-codes by name and modal group, M-codes,
axis and parameter words, and the warnings for words that are accepted but not modelled."""

from __future__ import annotations

from typing import NamedTuple

from feed_twin.gcode.codes import (
    GROUP_OF,
    M_KNOWN,
    NON_MODAL,
    TOOL_LENGTH_OFFSET,
    UNSUPPORTED_G,
    g_code_name,
)
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.lexer import Block, Word


class BlockWords(NamedTuple):
    """A block's words sorted by role."""

    modal: dict[str, tuple[str, Word]]  # modal group -> (code name, word)
    non_modal: dict[str, Word]  # code name -> word
    m_codes: list[tuple[int, Word]]
    other: dict[str, Word]  # letter -> word: axes, F S T I J K R P Q
    notes: list[str]  # warnings to report


def _error(file: str, reason: str, w: Word, line: int) -> GcodeError:
    return GcodeError(reason, file=file, line=line, column=w.column, word=w.text)


def sort_words(block: Block, *, allowed: frozenset[str], file: str) -> BlockWords:
    """Sort the block's words by role; reject unknown, unsupported and conflicting ones."""
    line = block.line
    words = BlockWords({}, {}, [], {}, [])
    words.notes.extend(
        f"line {line}: controller-specific word {note.text} ignored" for note in block.notes
    )
    for w in block.words:
        letter = w.letter
        if letter == "G":
            _sort_g_word(w, words, file, line)
        elif letter == "M":
            code = round(w.value)
            if abs(w.value - code) > 1e-9 or code not in M_KNOWN:
                raise _error(file, "unsupported M-code", w, line)
            words.m_codes.append((code, w))
        elif letter == "N":
            continue
        elif letter in ("D", "H"):
            words.notes.append(f"line {line}: {w.text} ignored (tool offsets are not modelled)")
        elif letter == "O" and len(block.words) == 1:
            words.notes.append(f"line {line}: program number {w.text} ignored")
        elif letter in allowed:
            if letter in words.other:
                raise _error(file, f"repeats {words.other[letter].text} in the same block", w, line)
            words.other[letter] = w
        else:
            if letter in ("A", "B", "C", "U", "V", "W"):
                reason = f"unknown word (axis {letter} is not configured)"
            elif letter == "O":
                reason = "unknown word (O-word subroutines are not supported)"
            else:
                reason = "unknown word"
            raise _error(file, reason, w, line)
    tool_length = words.modal.get(TOOL_LENGTH_OFFSET)
    if tool_length is not None and tool_length[0] == "G43":
        words.notes.append(
            f"line {line}: {tool_length[1].text} tool length taken as 0 (no tool table)"
        )
    return words


def _sort_g_word(w: Word, words: BlockWords, file: str, line: int) -> None:
    name = g_code_name(w.value)
    if name is None:
        raise _error(file, "unknown G-code", w, line)
    if name in UNSUPPORTED_G:
        raise _error(file, UNSUPPORTED_G[name], w, line)
    group = GROUP_OF.get(name)
    if group is None:
        raise _error(file, "unknown G-code", w, line)
    if group == NON_MODAL:
        words.non_modal[name] = w
        return
    if group in words.modal:
        first = words.modal[group][1]
        raise _error(file, f"conflicts with {first.text} (both in the {group} group)", w, line)
    words.modal[group] = (name, w)
