"""`node_log`, a node's log read back as records: rclpy's console prefix taken apart, lines
without it kept whole, a message's further (indented) lines joined to it. The lines below are
rclpy's own output (a node /cnc/x/sim logging with RCUTILS_CONSOLE_OUTPUT_FORMAT unset)."""

from __future__ import annotations

import pytest

from feed_twin.ros.node_log import LogRecord, parse_line, records

FAULT = (
    "drive fault 1 at t = 4.7500 s: following error 2.000 mm exceeds the limit 2.000 mm "
    "(controller.position.following_error_limit_m)"
)
LOG = f"""\
[INFO] [1795886291.508103768] [cnc.x.sim]: realtime off
PROGRESS 4.700
[WARN] [1795886291.507493778] [cnc.x.sim]: node 'controller' is slow: no progress for 0.50 s
[ERROR] [1795886291.506647406] [cnc.x.sim]: {FAULT}
  last setpoint 12.000 mm

TIMING {{"steps": 4750}}
"""


def test_a_prefixed_line_is_taken_apart() -> None:
    record = parse_line(f"[ERROR] [1795886291.506647406] [cnc.x.sim]: {FAULT}")
    assert record == LogRecord(
        message=FAULT, severity="ERROR", stamp_s=1795886291.506647406, logger="cnc.x.sim"
    )
    assert record.stamp_s == pytest.approx(1795886291.5066474, abs=1e-6)
    assert record.is_error and record.node == ("cnc/x", "sim")


@pytest.mark.parametrize(
    ("line", "severity", "logger", "message"),
    [
        ("[FATAL] [1795886291.5] [sim]: gone", "FATAL", "sim", "gone"),
        ("[DEBUG] [1795886291] [a.b.c]: ", "DEBUG", "a.b.c", ""),
        ("[WARN] [1795886291.507493778] [cnc.x.sim]: [x] kept", "WARN", "cnc.x.sim", "[x] kept"),
    ],
)
def test_every_severity_and_a_message_that_looks_like_a_prefix(
    line: str, severity: str, logger: str, message: str
) -> None:
    record = parse_line(line)
    assert (record.severity, record.logger, record.message) == (severity, logger, message)


@pytest.mark.parametrize(
    "line",
    [
        "stopped by SIGTERM",
        "[ERROR] the axis is on fire",  # no time, no logger: not rclpy's format
        "[NOTICE] [1795886291.5] [cnc.x.sim]: unknown severity",
        "ValueError: following_error_limit_m = -1 must be > 0",
    ],
)
def test_a_line_without_the_prefix_is_kept_whole(line: str) -> None:
    record = parse_line(line)
    assert record == LogRecord(message=line)
    assert record.node is None
    assert record.is_error == ("Error" in line)


def test_a_log_reads_as_records_with_continuations_joined_and_machine_lines_skipped() -> None:
    said = list(records(LOG, skip=("PROGRESS ", "TIMING ")))
    assert [r.severity for r in said] == ["INFO", "WARN", "ERROR"]
    assert said[-1].message == f"{FAULT}\n  last setpoint 12.000 mm"
    assert said[-1].node == ("cnc/x", "sim")
    assert [r.message for r in records(LOG)][-1] == 'TIMING {"steps": 4750}'


def test_a_traceback_after_a_record_is_its_own_record() -> None:
    text = (
        "[INFO] [1795886291.5] [cnc.x.controller]: started\n"
        "Traceback (most recent call last):\n"
        '  File "controller_node.py", line 3, in <module>\n'
        "ValueError: kv = 0 must be > 0\n"
    )
    said = list(records(text))
    assert [(r.severity, r.message.splitlines()[0]) for r in said] == [
        ("INFO", "started"),
        (None, "Traceback (most recent call last):"),
        (None, "ValueError: kv = 0 must be > 0"),
    ]
    assert [r.is_error for r in said] == [False, False, True]
    assert list(records("")) == [] and list(records("\n  \n")) == []
