"""What a node's log says of foreign messages while the run goes on (the ledger's counts come
at the end): the first refusal of each reason on a topic, every 1000th, and each foreign
publisher once, whichever of the node and its input guard saw it first."""

from __future__ import annotations

import re

import pytest

from feed_twin.ros.domain import reserve_domain_id

pytestmark = [pytest.mark.ros]

STATE, FEEDBACK = "/cnc/x/state", "/cnc/x/feedback"


def _log_lines(err: str, pattern: str) -> list[str]:
    return [line for line in err.splitlines() if re.search(pattern, line)]


def test_first_refusal_of_each_reason_and_each_foreign_publisher_logged_once(
    capfd, monkeypatch
) -> None:
    import rclpy
    from feed_twin_msgs.msg import AxisFeedback, AxisState

    from feed_twin.ros import runtime
    from feed_twin.ros.dds import init_context
    from feed_twin.ros.guarded import InputGuard
    from feed_twin.ros.runtime import FeedTwinNode, NodeOptions

    monkeypatch.setattr(runtime, "FOREIGN_GRAPH_S", 0.0)  # the graph read at every refusal
    with reserve_domain_id() as domain:
        context = init_context(domain_id=domain.domain_id)
        node = FeedTwinNode("sim", NodeOptions(machine="cnc", axis="x", peers=()), context=context)
        intruder = rclpy.create_node("intruder", context=context)
        try:
            intruder.create_publisher(AxisState, STATE, 10)
            intruder.create_publisher(AxisFeedback, FEEDBACK, 10)
            for reason in ["unsigned"] * 3 + ["replayed", "bad tag"] + ["unsigned"] * 995:
                node.refuse_foreign(STATE, reason)
            # the guard's look at the graph after the node's: the publisher is not named again
            guard = InputGuard(node, (STATE, FEEDBACK), "X")
            guard.check_graph()
            node.refuse_foreign(FEEDBACK, "unsigned")
            ledger = node.foreign_record().as_dict()
        finally:
            node.liveness.stop()
            intruder.destroy_node()
            node.destroy_node()
            context.try_shutdown()
    err = capfd.readouterr().err
    refused = _log_lines(err, r"refused \d+ foreign message\(s\) on /cnc/x/state")
    assert [re.findall(r"refused (\d+) .*\((.+)\)", line)[0] for line in refused] == [
        ("1", "unsigned"),
        ("4", "replayed"),
        ("5", "bad tag"),
        ("1000", "unsigned"),
    ]
    for topic in (STATE, FEEDBACK):
        named = _log_lines(err, f"foreign publisher on {topic}: node '/intruder'")
        assert len(named) == 1, named
        assert named[0].endswith("its messages are refused")
    assert ledger[STATE]["reasons"] == {"bad tag": 1, "replayed": 1, "unsigned": 998}
    assert ledger[FEEDBACK]["reasons"] == {"unsigned": 1}
    assert all(p.startswith("node '/intruder'") for t in ledger.values() for p in t["publishers"])
