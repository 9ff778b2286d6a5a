"""What every `feed-twin run` prints at its end, whatever the mode: the RunReport's labelled
lines with units and no raw values, and the same JSON keys (feed_twin.nodeset.run_report)."""

from __future__ import annotations

import json
import re

from feed_twin.nodeset.run_report import RunReport

_EMPTY = RunReport(mode="any", exit_code=0)
# the labels of the report's own rows (after the mode's figure lines)
LABELS = tuple(line.split(":", 1)[0] for line in _EMPTY.format().splitlines())
KEYS = frozenset(_EMPTY.as_dict())
# a raw value: Python's missing values and reprs, or a float printed with all its digits
RAW = re.compile(r"\b(nan|NaN|None|inf)\b|<[\w.]+ object at|\d\.\d{7,}")


def assert_report(stdout: str) -> dict:
    """The run's report in `stdout` has every row once, no raw value, and its last line is the
    JSON object with every key of the report; returns that object."""
    lines = stdout.strip().splitlines()
    text = "\n".join(lines[:-1])
    for label in LABELS:
        rows = [ln for ln in lines if ln.startswith(f"{label}:")]
        assert len(rows) == 1, f"{label!r} rows: {rows}\n{text}"
    raw = RAW.search(text)
    assert raw is None, f"a raw value {raw.group(0)!r} in:\n{text}"
    record = json.loads(lines[-1])
    assert set(record) >= KEYS, f"missing keys: {sorted(KEYS - set(record))}"
    return record
