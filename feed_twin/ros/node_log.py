"""A node's log read back as records, for the reason a run gives when a node fails.

rclpy's default console format (RCUTILS_CONSOLE_OUTPUT_FORMAT unset) writes each call as
`[SEVERITY] [<epoch s>.<ns>] [<logger>]: <message>`, the logger being the node's namespace and
name joined by dots (`cnc.x.sim` for /cnc/x/sim). A message of several lines is written as it
is: its further lines carry no prefix. `records` reads such text: a prefixed line opens a
record, an indented line without the prefix continues the one before it (a multi-line message,
a traceback's frames), any other line (a `print`, a Python traceback's last line) is a record
of its own without severity, time or logger.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass

_PREFIX = re.compile(
    r"^\[(?P<severity>DEBUG|INFO|WARN|ERROR|FATAL)\] "
    r"\[(?P<stamp>\d+(?:\.\d+)?)\] "
    r"\[(?P<logger>[^\]]*)\]: ?"
)
ERROR_SEVERITIES = ("ERROR", "FATAL")


@dataclass(frozen=True, kw_only=True)
class LogRecord:
    message: str  # the text after the prefix, its further lines joined by "\n"
    severity: str | None = None  # DEBUG, INFO, WARN, ERROR or FATAL; None: no rclpy prefix
    stamp_s: float | None = None  # [s since the epoch] when it was logged
    logger: str | None = None  # e.g. "cnc.x.sim"

    @property
    def is_error(self) -> bool:
        """An ERROR/FATAL record, or an unprefixed line that names an error (a traceback's
        `ValueError: ...`, an `Error` a node printed)."""
        if self.severity is not None:
            return self.severity in ERROR_SEVERITIES
        return "Error" in self.message.partition("\n")[0]

    @property
    def node(self) -> tuple[str, str] | None:
        """(namespace, name) of the node that logged it, from its logger: ("cnc/x", "sim");
        None for a record without logger."""
        if not self.logger:
            return None
        namespace, _, name = self.logger.rpartition(".")
        return namespace.replace(".", "/"), name


def parse_line(line: str) -> LogRecord:
    """One line as a record: rclpy's prefix taken apart, or the whole line as the message."""
    match = _PREFIX.match(line)
    if match is None:
        return LogRecord(message=line)
    return LogRecord(
        message=line[match.end() :],
        severity=match["severity"],
        stamp_s=float(match["stamp"]),
        logger=match["logger"],
    )


def records(text: str, *, skip: tuple[str, ...] = ()) -> Iterator[LogRecord]:
    """The records of a log's `text`, blank lines and lines starting with one of `skip`
    (machine-read lines such as `PROGRESS `) left out."""
    current: LogRecord | None = None
    more: list[str] = []
    for line in text.splitlines():
        if not line.strip() or (skip and line.startswith(skip)):
            continue
        if current is not None and line[0].isspace():
            more.append(line)
            continue
        if current is not None:
            yield _joined(current, more)
        current, more = parse_line(line), []
    if current is not None:
        yield _joined(current, more)


def _joined(record: LogRecord, more: list[str]) -> LogRecord:
    if not more:
        return record
    return LogRecord(
        message="\n".join([record.message, *more]),
        severity=record.severity,
        stamp_s=record.stamp_s,
        logger=record.logger,
    )
