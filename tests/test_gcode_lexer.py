"""Lexer: words with columns from RS274/NGC, Fanuc and Sinumerik text; every error message."""

from __future__ import annotations

import pytest

from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.lexer import Block, iter_source_lines, lex_line


def lex(text: str, *, block_delete: bool = True) -> Block:
    block = lex_line(text, 7, file="p.ngc", block_delete=block_delete)
    assert block is not None, f"{text!r}: no block"
    return block


def test_words_letters_values_and_columns():
    block = lex("N10 g1 x-1.5 Y.25 z+3 F1200.")
    assert [(w.letter, w.value, w.column) for w in block.words] == [
        ("N", 10.0, 1),
        ("G", 1.0, 5),
        ("X", -1.5, 8),
        ("Y", 0.25, 14),
        ("Z", 3.0, 19),
        ("F", 1200.0, 23),
    ]
    assert block.line == 7


def test_whitespace_inside_words_and_no_spaces_between_words():
    block = lex("G 1X - 2.5Y3 (comment) ; trailing")
    assert [(w.letter, w.value) for w in block.words] == [("G", 1.0), ("X", -2.5), ("Y", 3.0)]
    assert block.words[1].text == "X-2.5"
    compact = lex("G1X10Y-2")
    assert [(w.letter, w.value) for w in compact.words] == [("G", 1), ("X", 10), ("Y", -2)]


@pytest.mark.parametrize(
    "text", ["", "   ", "%", "(only a comment)", "; semicolon comment", "/G1 X5", "  % end"]
)
def test_lines_without_blocks(text):
    assert lex_line(text, 7, file="p.ngc", block_delete=True) is None


def test_block_delete_switch_off_keeps_the_block():
    block = lex("/G1 X5", block_delete=False)
    assert [(w.letter, w.value, w.column) for w in block.words] == [("G", 1.0, 2), ("X", 5.0, 5)]


def test_sinumerik_items_become_notes_and_axis_assignment_is_a_word():
    block = lex('T="DRILL_10" MSG("roughing") R1=5 X=12.5')
    assert [n.text for n in block.notes] == ['T="DRILL_10"', 'MSG("roughing")', "R1=5"]
    assert [(w.letter, w.value) for w in block.words] == [("X", 12.5)]
    assert block.notes[0].column == 1


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("G1 X5 (open comment", "p.ngc:7:7: word '(': comment '(' is never closed"),
        ("G1 X#1", "p.ngc:7:4: word 'X#1': parameters (#) are not supported"),
        ("#1=5", "p.ngc:7:1: word '#': parameters (#) are not supported"),
        ("G1 X[1+2]", "p.ngc:7:4: word 'X[1+2]': expressions [...] are not supported"),
        ("G1 X", "p.ngc:7:4: word 'X': word has no number"),
        ("G1 X5 $", "p.ngc:7:7: word '$': unexpected character"),
        ("=5 G1", "p.ngc:7:1: word '=': assignment without a name"),
        ('G1 "X"', "p.ngc:7:4: word '\"': string outside an assignment"),
    ],
)
def test_lexer_errors_name_file_line_column_and_word(text, message):
    with pytest.raises(GcodeError) as info:
        lex(text)
    assert str(info.value) == message
    assert info.value.line == 7


def test_binary_file_is_rejected_with_a_clear_message(tmp_path):
    path = tmp_path / "prog.nc"
    path.write_bytes(b"G1 X1\n\x89PNG\x00\x01")
    file, lines = iter_source_lines(path)
    with pytest.raises(GcodeError, match=r"prog.nc:2:1: not a text G-code file \(invalid UTF-8"):
        list(lines)
    path.write_bytes(b"G1 X1\nG1\x00X2\n")
    with pytest.raises(GcodeError, match=r"prog.nc:2:3: not a text G-code file \(NUL byte"):
        list(iter_source_lines(path)[1])


def test_missing_file_and_text_source(tmp_path):
    with pytest.raises(GcodeError, match="nothere.ngc: no such G-code file"):
        iter_source_lines(tmp_path / "nothere.ngc")
    with pytest.raises(GcodeError, match=r"^part\.MPF: no such G-code file$"):
        iter_source_lines("part.MPF")
    file, lines = iter_source_lines("G0 X1\nG1 Y2 F100")
    assert file == "<text>"
    assert list(lines) == [(1, "G0 X1"), (2, "G1 Y2 F100")]
