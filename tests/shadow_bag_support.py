"""The fingerprint of a `feed-twin run --shadow` bag, read back with an independent reader
(rosbags): every topic's type, the message count of every topic whose count is the run's own,
and a digest of the message data of every topic a lockstep run computes the same each time
(`fingerprint(bag, the program's directory)`).

Found by recording config/axis_default.yaml's shadow run of tests/fixtures/gcode/sample.ngc
three times (two on main before the axis's shadow moved to the machine shadow's runner, one
after) and comparing every message: the command, the stand-in's joint_states, the twin's state,
the clock, program_state and run_state are byte-equal; the twin's residual is equal but for its
two rolling RMS values (their sums run over the samples in the blocks the twin happened to
take, so their last bits vary); how many health verdicts the twin makes depends on those
blocks too (tests/test_shadow_run.py); heartbeats and /rosout carry wall time. program_state
names the program's file: its directory is left out.

    python tests/shadow_bag_support.py BAG PROGRAM_DIR > tests/fixtures/shadow_bag/NAME.json

writes a bag's fingerprint (the reference of tests/test_shadow_run.py's guard was recorded so
from main before the move, and again so from the steady run's bag when the default jerk limit
came from the axis's first mode: two runs gave the same fingerprint, and a run with the former
limits, 60/60/50 m/s^3, gave the former reference exactly; and again when the jerk filter's
integral became two doubles: the command's positions moved by at most 4.9e-14 m, its
velocities and accelerations at 65 of 5365 samples by 5e-12 m/s and 1.8e-9 m/s^2, and with
them the stand-in's and the twin's messages; two runs gave the same fingerprint).
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import fields, is_dataclass
from typing import Any

# the topics whose message count and data are not the run's own (wall time, the twin's blocks)
VARYING_TOPICS = ("/cnc/x/heartbeat", "/rosout", "/cnc/x/twin/health")
# topic -> the fields left out of its digest: those whose last bits depend on how the twin
# grouped its samples; the topics here are read decoded (the program's directory left out)
DECODED_TOPICS: dict[str, tuple[str, ...]] = {
    "/cnc/x/twin/residual": ("following_error_deviation_rms", "effort_deviation_rms"),
    "/cnc/x/program_state": (),
}


def _canonical(value: Any, directory: str) -> Any:
    """A message as plain data, floats by their exact hex form, `directory` left out of text."""
    if is_dataclass(value):
        return [_canonical(getattr(value, f.name), directory) for f in fields(value)]
    if isinstance(value, float):
        return value.hex()
    if isinstance(value, str):
        return value.replace(directory, "<dir>")
    if isinstance(value, (list, tuple)):
        return [_canonical(v, directory) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays of a message's sequence fields
        return _canonical(value.tolist(), directory)
    return value


def fingerprint(bag: str, directory: str) -> dict[str, dict[str, Any]]:
    """Topic -> {"type", "count", "data" (digest)}; count and data None on a varying topic,
    data None on a topic without messages."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from rosbags_support import decode

    store = get_typestore(Stores.EMPTY)
    out: dict[str, dict[str, Any]] = {}
    digests: dict[str, Any] = {}
    with Reader(bag) as reader:
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
            entry = out.setdefault(conn.topic, {"type": conn.msgtype, "count": 0, "data": None})
            entry["count"] += conn.msgcount
        wanted = [c for c in reader.connections if c.topic not in VARYING_TOPICS]
        for conn, _, raw in reader.messages(wanted):
            h = digests.setdefault(conn.topic, hashlib.sha256())
            skipped = DECODED_TOPICS.get(conn.topic)
            if skipped is None:
                h.update(raw)
                continue
            message = decode(store, raw, conn.msgtype)
            kept = [_canonical(getattr(message, f.name), directory) for f in fields(message)
                    if f.name not in skipped]  # fmt: skip
            h.update(json.dumps(kept).encode())
    for topic, entry in out.items():
        if topic in VARYING_TOPICS:
            entry["count"] = None
        else:
            entry["data"] = digests[topic].hexdigest() if topic in digests else None
    return dict(sorted(out.items()))


if __name__ == "__main__":
    print(json.dumps(fingerprint(sys.argv[1], sys.argv[2]), indent=1))
