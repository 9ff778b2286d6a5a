"""The ledger of foreign messages: counts by topic and reason, publishers named, merged over the
nodes that heard the same messages, printed as the run's own lines and JSON."""

from __future__ import annotations

from feed_twin.nodeset.foreign import UNKNOWN_PUBLISHER, ForeignLedger, merge, parse_log

INTRUDER = "node '/intruder' (publisher gid 01.0f.aa)"


def test_counts_by_topic_and_reason_with_the_publishers_named():
    ledger = ForeignLedger()
    for _ in range(3):
        ledger.refuse("/cnc/x/state", "bad tag")
    assert ledger.refuse("/cnc/x/state", "replayed") == 4
    ledger.refuse("/cnc/x/feedback", "unsigned")
    assert ledger.name("/cnc/x/state", INTRUDER) and not ledger.name("/cnc/x/state", INTRUDER)
    ledger.name("/cnc/x/command", "node '/tool' (publisher gid 02)")  # heard, nothing sent yet
    assert ledger.count == 5
    tool = "node '/tool' (publisher gid 02)"
    assert ledger.as_dict() == {
        "/cnc/x/command": {"messages": 0, "reasons": {}, "publishers": [tool]},
        "/cnc/x/feedback": {
            "messages": 1, "reasons": {"unsigned": 1}, "publishers": [UNKNOWN_PUBLISHER],
        },
        "/cnc/x/state": {
            "messages": 4, "reasons": {"bad tag": 3, "replayed": 1}, "publishers": [INTRUDER],
        },
    }  # fmt: skip
    assert ledger.lines() == [
        f"foreign messages: on /cnc/x/command; from {tool}",
        f"foreign messages: 1 on /cnc/x/feedback (unsigned 1), dropped; from {UNKNOWN_PUBLISHER}",
        f"foreign messages: 4 on /cnc/x/state (bad tag 3, replayed 1), dropped; from {INTRUDER}",
    ]


def test_nodes_that_heard_the_same_messages_merge_to_the_largest_count():
    recorder, controller = ForeignLedger(), ForeignLedger()
    for _ in range(10):
        recorder.refuse("/cnc/x/feedback", "bad tag")
    for _ in range(9):  # the controller started listening a little later
        controller.refuse("/cnc/x/feedback", "bad tag")
    controller.name("/cnc/x/feedback", INTRUDER)
    text = f"PROGRESS 1.0\n{recorder.log_line()}\nFOREIGN {{not json\n{controller.log_line()}\n"
    merged = merge(parse_log(text))
    assert merged.as_dict() == {
        "/cnc/x/feedback": {"messages": 10, "reasons": {"bad tag": 10}, "publishers": [INTRUDER]}
    }
    assert merge([]).as_dict() == {} and merge([]).lines() == []
