"""The ROS side of feed_twin.nodeset.guard: a node's guarded command inputs.

`InputGuard` belongs to a node that takes commands (controller, sim): it knows the run token,
refuses messages (warning in the log, throttled, and a HealthStatus on `<ns>/health`), and
every second looks for publishers of its command topics that are not nodes of the run.
"""

from __future__ import annotations

import math
import os
import time

from feed_twin_msgs.msg import HealthStatus

from feed_twin.nodeset.guard import OPEN_NC_ENV, CommandGuard, Endpoint, run_token
from feed_twin.nodeset.roles import node_role, roles_where
from feed_twin.ros.dds import LATCHED_QOS

# Node names of a run: the roles, the recorder's data node and each role's liveness node.
RUN_ROLES = tuple(node_role(name).node_name for name in roles_where(own_node=True))
OWN_NODES = frozenset((*RUN_ROLES, "recorder_data", *(f"{role}_liveness" for role in RUN_ROLES)))
GRAPH_PERIOD_S = 1.0
# A refused message means someone is sending: the graph is read then too, at most this often,
# so a publisher is named even in a run shorter than GRAPH_PERIOD_S.
GRAPH_ON_REFUSAL_S = 0.1


class InputGuard:
    def __init__(self, node, topics: tuple[str, ...], axis_label: str) -> None:
        self.node = node
        self.topics = topics
        self.axis_label = axis_label
        self.token = run_token(os.environ)
        # what the NC's messages (AxisCommand, program_state) must carry: nothing when they
        # come from an external NC (`feed-twin run --no-gcode`)
        self.nc_token = "" if os.environ.get(OPEN_NC_ENV) == "1" else self.token
        self.guard = CommandGuard(own_nodes=OWN_NODES, namespace=node.topics.namespace)
        self._health = node.create_publisher(HealthStatus, node.topics.health, LATCHED_QOS)
        node.create_timer(GRAPH_PERIOD_S, self.check_graph, clock=node.wall)
        self._graph_read_at = -math.inf  # [s] monotonic time of the last look at the graph

    def refuse(self, kind: str, topic: str, detail: str) -> None:
        """Drop one message: count it, warn (the first one, then every 1000th) and say so on
        the health topic."""
        count = self.guard.refuse(kind)
        if count == 1 or count % 1000 == 0:
            text = f"refused {count} message(s) on {topic}: {detail}"
            self.node.get_logger().warning(text)
            self._publish(text)
        if time.monotonic() - self._graph_read_at >= GRAPH_ON_REFUSAL_S:
            self.check_graph()

    def check_graph(self) -> None:
        self._graph_read_at = time.monotonic()
        for topic in self.topics:
            try:
                infos = self.node.get_publishers_info_by_topic(topic)
            except Exception:  # noqa: BLE001 - the graph is read again in a second
                return
            endpoints = [
                Endpoint(
                    node_name=i.node_name,
                    node_namespace=i.node_namespace,
                    gid=".".join(f"{b:02x}" for b in i.endpoint_gid),
                )
                for i in infos
            ]
            for e in self.guard.foreign(endpoints):
                text = f"foreign publisher on {topic}: {e.describe()}; its messages are refused"
                self.node.get_logger().warning(text)
                self._publish(text)

    def _publish(self, text: str) -> None:
        msg = HealthStatus(axis=self.axis_label, level=HealthStatus.WARN, message=text[:500])
        self._health.publish(msg)
