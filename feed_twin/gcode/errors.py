"""The one error type of the G-code pipeline: where in which file, which word, and why."""

from __future__ import annotations

MAX_WORD_SHOWN = 40  # characters of a word an error message quotes


class GcodeError(ValueError):
    """A program cannot be run as written.

    The message reads `file:line:col: word 'G93': reason`; without a word (an empty or binary
    file) it reads `file: reason`. Line and column are 1-based, as editors show them.
    """

    def __init__(
        self,
        reason: str,
        *,
        file: str,
        line: int | None = None,
        column: int | None = None,
        word: str | None = None,
    ) -> None:
        self.reason = reason
        self.file = file
        self.line = line
        self.column = column
        self.word = word
        where = file
        if line is not None:
            where += f":{line}"
            if column is not None:
                where += f":{column}"
        shown = word
        if word is not None and len(word) > MAX_WORD_SHOWN:
            # A runaway word (a whole line of digits) is not echoed: its start says enough.
            shown = f"{word[:MAX_WORD_SHOWN]}... ({len(word)} characters)"
        text = f"{where}: word {shown!r}: {reason}" if word is not None else f"{where}: {reason}"
        super().__init__(text)
