"""The recorder closes a shadow run's bag only once the shadow twin has left the graph: the twin
decides its last samples after its inputs fall quiet, which on a loaded host can come after the
recorder's own quiet period (a bag one twin sample short, seen at load 7)."""

from __future__ import annotations

import time

import pytest

from feed_twin.ros.domain import reserve_domain_id

pytestmark = [pytest.mark.ros]


def _spin_until(node, predicate, limit_s: float) -> float:
    """Run the recorder's timers until `predicate()` or `limit_s`; the seconds it took."""
    from rclpy.executors import SingleThreadedExecutor

    start = time.monotonic()
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while not predicate() and time.monotonic() - start < limit_s:
            node.poll()
            executor.spin_once(timeout_sec=0.01)
    finally:
        executor.remove_node(node)
    return time.monotonic() - start


def test_the_bag_stays_open_while_the_shadow_twin_is_in_the_graph(tmp_path) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    from feed_twin.ros.recorder_node import DRAIN_QUIET_S, RecorderNode
    from feed_twin.ros.runtime import NodeOptions

    feed_twin_msgs = pytest.importorskip("feed_twin_msgs.msg")
    with reserve_domain_id() as domain:
        context = Context()
        rclpy.init(
            context=context,
            domain_id=domain.domain_id,
            signal_handler_options=SignalHandlerOptions.NO,
        )
        try:
            options = NodeOptions(machine="cnc", axis="x", peers=())
            recorder = RecorderNode(
                options, tmp_path / "bag", twin_namespace="/cnc/x/twin", context=context
            )
            twin = rclpy.create_node("twin", namespace="/cnc/x", context=context)
            twin.create_publisher(feed_twin_msgs.AxisState, "/cnc/x/twin/state", 10)
            recorder.on_run_done("done: program finished")
            waited = _spin_until(recorder, lambda: recorder.done, 4 * DRAIN_QUIET_S)
            assert not recorder.done, f"closed after {waited:.2f} s with the twin still there"
            twin.destroy_node()
            waited = _spin_until(recorder, lambda: recorder.done, 5.0)
            assert recorder.done and recorder.exit_code == 0, recorder.exit_message
            assert waited < 2.0
            recorder.on_shutdown("end")
            recorder.destroy_node()
        finally:
            context.try_shutdown()
