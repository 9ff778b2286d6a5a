"""What every `feed-twin run` prints at its end, whatever the mode: the RunReport's labelled
lines with units and no raw values, and the same JSON keys (feed_twin.nodeset.run_report).

Every mode's finished run is checked with its mode named (`assert_report(out, mode=...)`): the
axis and machine configs each in `run` (test_nodes_run, test_machine_nodes), `run --shadow`
(test_shadow_run, test_machine_shadow_nodes) and `run --nc linuxcnc --shadow`
(test_linuxcnc_shadow, test_linuxcnc_machine_shadow), in-process in test_run_report_modes.
MODES lists them; test_run_report_modes checks that each is named by one of those tests."""

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


# the modes of a finished `feed-twin run` and the test file that checks each one's report
MODES = {
    "axis nodes": "test_nodes_run.py",
    "axis nodes shadow": "test_shadow_run.py",
    "axis LinuxCNC shadow": "test_linuxcnc_shadow.py",
    "machine nodes": "test_machine_nodes.py",
    "machine nodes shadow": "test_machine_shadow_nodes.py",
    "machine LinuxCNC shadow": "test_linuxcnc_machine_shadow.py",
}


def assert_report(stdout: str, mode: str | None = None) -> dict:
    """The run's report in `stdout` has every row once, no raw value, and its last line is the
    JSON object with every key of the report; returns that object. With `mode`: the run ended
    normally in that mode, and names its bag, logs, ROS domain, samples and simulated time
    (each mode gives them all)."""
    lines = stdout.strip().splitlines()
    text = "\n".join(lines[:-1])
    for label in LABELS:
        rows = [ln for ln in lines if ln.startswith(f"{label}:")]
        assert len(rows) == 1, f"{label!r} rows: {rows}\n{text}"
    raw = RAW.search(text)
    assert raw is None, f"a raw value {raw.group(0)!r} in:\n{text}"
    record = json.loads(lines[-1])
    assert set(record) >= KEYS, f"missing keys: {sorted(KEYS - set(record))}"
    if mode is not None:
        assert record["mode"] == mode and f"run:                  {mode}, ended normally" in text
        named = ("bag", "logs", "ros_domain", "samples", "timing_sim_time_s")
        missing = [k for k in named if record[k] is None]
        assert not missing, f"{mode}: the report names no {', '.join(missing)}"
    return record
