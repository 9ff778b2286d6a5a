"""The ROS side of feed_twin.nodeset.guard: a node's guarded command inputs.

`InputGuard` belongs to a node that takes commands (controller, sim): it admits only messages
signed by the run's nodes (feed_twin.nodeset.auth, through the node's `admit`; the commands of
an external NC under `--no-gcode` unsigned), refuses malformed ones (warning in the log,
throttled, and a HealthStatus on `<ns>/health`), and every second looks for publishers of its
input topics that are not nodes of the run, naming them in the node's ledger of foreign
messages (feed_twin.nodeset.foreign). `foreign_publishers` is that look, for any node.
"""

from __future__ import annotations

import math
import os
import time

from feed_twin_msgs.msg import HealthStatus

from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.foreign import foreign_publisher_text
from feed_twin.nodeset.guard import OPEN_NC_ENV, CommandGuard, Endpoint
from feed_twin.nodeset.roles import node_role, roles_where
from feed_twin.ros.dds import LATCHED_QOS

# Node names of a run: the roles, the recorder's data node and each role's liveness node.
RUN_ROLES = tuple(node_role(name).node_name for name in roles_where(own_node=True))
OWN_NODES = frozenset((*RUN_ROLES, "recorder_data", *(f"{role}_liveness" for role in RUN_ROLES)))
GRAPH_PERIOD_S = 1.0
# A refused message means someone is sending: the graph is read then too, at most this often,
# so a publisher is named even in a run shorter than GRAPH_PERIOD_S.
GRAPH_ON_REFUSAL_S = 0.1
HEALTH = FlatCodec(msg_types.HEALTH_STATUS)


def endpoints_of(node, topic: str) -> list[Endpoint]:
    return [
        Endpoint(
            node_name=i.node_name,
            node_namespace=i.node_namespace,
            gid=".".join(f"{b:02x}" for b in i.endpoint_gid),
        )
        for i in node.get_publishers_info_by_topic(topic)
    ]


def foreign_publishers(node, topic: str) -> list[str]:
    """The publishers of `topic` in the graph that are not nodes of `node`'s run, described
    (node name and endpoint GID)."""
    guard = CommandGuard(own_nodes=OWN_NODES, namespace=node.topics.namespace)
    return [e.describe() for e in guard.foreign(endpoints_of(node, topic))]


class InputGuard:
    def __init__(
        self, node, topics: tuple[str, ...], axis_label: str, nc_topics: tuple[str, ...] = ()
    ) -> None:
        self.node = node
        self.topics = topics
        self.axis_label = axis_label
        # the NC's messages (AxisCommand, program_state: `nc_topics`) come unsigned from an
        # external NC (`feed-twin run --no-gcode`)
        self.open_nc = os.environ.get(OPEN_NC_ENV) == "1"
        self.nc_topics = frozenset(nc_topics)
        self.guard = CommandGuard(own_nodes=OWN_NODES, namespace=node.topics.namespace)
        self._health = node.create_publisher(HealthStatus, node.topics.health, LATCHED_QOS)
        node.create_timer(GRAPH_PERIOD_S, self.check_graph, clock=node.wall)
        self._graph_read_at = -math.inf  # [s] monotonic time of the last look at the graph

    def admit(self, topic: str, data: bytes) -> bytes | None:
        """The message as its node made it, when the run's (node.admit); None: refused."""
        if self.open_nc and topic in self.nc_topics:
            return data
        body = self.node.admit(topic, data)
        if body is None:
            self._look_soon()
        return body

    def admit_text(self, topic: str, text: str) -> str | None:
        if self.open_nc and topic in self.nc_topics:
            return text
        body = self.node.admit_text(topic, text)
        if body is None:
            self._look_soon()
        return body

    def _look_soon(self) -> None:
        if time.monotonic() - self._graph_read_at >= GRAPH_ON_REFUSAL_S:
            self.check_graph()

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
                endpoints = endpoints_of(self.node, topic)
            except Exception:  # noqa: BLE001 - the graph is read again in a second
                return
            for e in self.guard.foreign(endpoints):
                text = foreign_publisher_text(topic, e.describe())
                if self.node.foreign.name(topic, e.describe()):  # else the node logged it
                    self.node.get_logger().warning(text)
                self._publish(text)

    def _publish(self, text: str) -> None:
        data = HEALTH.encode_map(
            {"axis": self.axis_label, "level": HealthStatus.WARN, "message": text[:500]}
        )
        topic = self.node.topics.health
        self._health.publish(self.node.auth.sign(topic, data))
