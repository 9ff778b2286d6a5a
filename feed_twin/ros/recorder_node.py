"""The recorder node: every topic of the axis, as exact wire bytes, into a rosbag2 MCAP bag.

It takes the serialised messages (`raw=True`), so the stored bytes are what DDS delivered (no
deserialisation, no re-serialisation padding), and writes them through
`feed_twin.io.bag.BagWriter`. Besides the node set's own topics (subscribed at start, so the
first messages are not missed) it scans the graph every 0.2 s and adds any other topic under the
axis namespace, plus /clock and /rosout, with the QoS its publisher offers. Log time is the
receive time and publish time the writer's source timestamp (ns, system clock), as rosbag2
records them.

The data subscriptions belong to a second node that no executor spins: the recorder drains
their queues every DRAIN_PERIOD_S (`take_message` until empty) instead of waking once per
message. A lockstep run sends four or five messages per exchange at several thousand exchanges
per second; a callback per message would make the recorder the largest CPU user of the node set
and steal the cores the controller and the sim wait for. The subscriptions' history (DATA_QOS
depth) holds what arrives between two drains.

With `ros.record_batch` N > 0 (a machine's node set) the sim's feedback, state and joint states
and the controller's DriveCommand come packed, N exchanges to a RecordBatch on
`<namespace>/record/<role>` (feed_twin.nodeset.record_batch): the recorder subscribes to those
instead of to the topics themselves and writes each message under its own topic, logged at its
publish time. Producers of those topics other than the sim and controller nodes (a stand-in)
do not pack: the recorder reads the packed copies of a role only where its peers include that
role's node (`--peers`), and the topics themselves elsewhere. A LinuxCNC bridge among the peers
always packs: each axis's command and joint states (and the first axis's servo samples) come
in RecordBatches on `<namespace>/linuxcnc/batch` (feed_twin/ros/linuxcnc_node.py).

A machine's recorder (`--machine-axes`, `--command-axes`; feed_twin.machine.nodes) records
every axis of the machine into the one bag: the node-set topics of each axis with nodes, the
command of each axis without, and whatever else appears under `/<machine>/`.

Only the run's own messages are recorded (feed_twin.nodeset.auth): a message whose type has a
place for the run's signature (a Header first, or a String) is written as its node made it once
its signature checks, and dropped, counted by topic and reason, with the topic's foreign
publishers named, otherwise (feed_twin.nodeset.foreign; the runner reports them). Under
`--no-gcode` the external NC's commands and program states are recorded unsigned. Types with
no such place (the clock, /rosout, RecordBatch) are recorded as they come.

The run ends when the sim node (of every axis) announces it on `run_state`; the recorder then
drains what is still in flight (until 0.3 s without a message and no shadow twin left in the
graph, at most 30 s) and closes the bag. On SIGINT, SIGTERM or a lost peer it closes the bag as
well.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import re
import struct
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription

from feed_twin.io import msg_types
from feed_twin.io.bag import BagError, BagWriter, QosProfile
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.auth import RunAuth
from feed_twin.nodeset.guard import OPEN_NC_ENV
from feed_twin.nodeset.record_batch import unpack
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.summary import LiveFeeds
from feed_twin.nodeset.topics import CONTROLLER_NODE, RECORDER_NODE, SIM_NODE, AxisTopics
from feed_twin.ros.batched import batch_qos
from feed_twin.ros.dds import DATA_QOS, HEARTBEAT_QOS, LATCHED_QOS
from feed_twin.ros.runtime import (
    EXIT_ERROR,
    EXIT_OK,
    EXIT_PEER_LOST,
    EXIT_SIGNAL,
    FeedTwinNode,
    NodeOptions,
    node_main,
    process_key,
)

LINUXCNC_NODE = node_role("linuxcnc").name  # a peer whose messages come packed

Check = Callable[[bytes], "bytes | None"]  # a message as its node made it, or None: foreign
DRAIN_QUIET_S = 0.3
# a shadow twin's output (under <axis>/twin, feed_twin.shadow.replay.twin_namespace): the last
# topic of a run to end
TWIN_STATE_SUFFIX = node_role("twin").topic("/twin", "state")
DRAIN_MAX_S = 30.0  # a recorder starved of CPU may lag seconds behind the graph
SCAN_PERIOD_S = 0.2
DRAIN_PERIOD_S = 0.005  # [s] between two drains of the data subscriptions
EXTRA_GLOBAL_TOPICS = ("/rosout",)
# The types whose messages carry the run's signature in header.frame_id (a Header first).
SIGNED_TYPES = frozenset(
    (
        msg_types.AXIS_COMMAND, msg_types.AXIS_FEEDBACK, msg_types.AXIS_STATE,
        msg_types.DRIVE_COMMAND, msg_types.HEALTH_STATUS, msg_types.TWIN_RESIDUAL,
        msg_types.JOINT_STATE, "feed_twin_msgs/msg/ServoSample",
    )
)  # fmt: skip
STRING = FlatCodec(msg_types.STRING)


def message_class(type_name: str) -> type:
    package, _, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def _bag_qos(qos: QoSProfile) -> QosProfile:
    def seconds(duration: object) -> float:
        ns = getattr(duration, "nanoseconds", None)
        return float("inf") if ns is None or ns >= 2**63 - 1 or ns == 0 else ns * 1e-9

    return QosProfile(
        history="keep_all" if qos.history.value == 2 else "keep_last",
        depth=int(qos.depth),
        reliability="best_effort"
        if qos.reliability == ReliabilityPolicy.BEST_EFFORT
        else "reliable",
        durability=(
            "transient_local" if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL else "volatile"
        ),
        deadline_s=seconds(qos.deadline),
        lifespan_s=seconds(qos.lifespan),
        liveliness_lease_duration_s=seconds(qos.liveliness_lease_duration),
    )


class RecorderNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        bag_path: Path,
        *,
        live_url: str | None = None,
        twin_namespace: str | None = None,
        record_batch: int = 0,
        context=None,
    ) -> None:
        super().__init__(RECORDER_NODE, options, context=context)
        self.bag = BagWriter(bag_path)
        # every served axis (a machine's recorder serves them all)
        served = list(options.axis_topics().values())
        self.live = LiveFeeds(served, live_url) if live_url else None
        self.bag_path = bag_path
        self._recorded: dict[str, object] = {}
        # Spun by nobody: `_drain` takes its messages (see the module docstring).
        self._data_node = Node(
            f"{RECORDER_NODE}_data", namespace=self.topics.namespace, context=self.context
        )
        # (topic, subscription, counts, the run's check or None, live feed): `counts` when
        # its messages show the run still sending (not heartbeats)
        self._takers: list[tuple[str, Subscription, bool, Check | None, LiveFeeds | None]] = []
        # (batch topic, subscription, the topics it may carry); record_batch > 0
        self._batch_takers: list[tuple[str, Subscription, frozenset[str]]] = []
        self._next_drain = 0.0
        self._last_message = time.monotonic()
        self._ending_since: float | None = None
        self.end_reason = ""
        self._peer_lost: str | None = None
        self._peers_lost: set[str] = set()
        self._signal: str | None = None
        self._twin_states: set[str] = set()
        served = list(options.axis_topics().values())
        known: dict[str, str] = {}
        self._record_auth = RunAuth(process_key())
        self._open_topics: set[str] = set()  # recorded unsigned: an external NC's
        qos_for = {}
        self._heartbeats = set()
        for topics in served:
            known.update(topics.types())
            # the G-code node's packed copies for the controllers (gcode_node --command-batch):
            # recorded from `command` instead, so the graph scan passes them by
            self._recorded[topics.command_batch] = None
            if os.environ.get(OPEN_NC_ENV) == "1":
                self._open_topics |= {topics.command, topics.program_state}
            qos_for[topics.program_state] = qos_for[topics.run_state] = LATCHED_QOS
            qos_for[topics.heartbeat] = HEARTBEAT_QOS
            self._heartbeats.add(topics.heartbeat)
        if options.other_axes or options.command_axes:
            # each sim publishes its axis's clock (sim_node --axis-clock); nobody /clock
            clock_type = known.pop(AxisTopics.clock)
            for topics in served:
                known[f"{topics.namespace}/clock"] = clock_type
        for axis in options.command_axes:
            command = AxisTopics(machine=options.machine, axis=axis).command
            known[command] = msg_types.AXIS_COMMAND
        machine = options.other_axes or options.command_axes
        self._scan_prefix = f"/{options.machine}/" if machine else None
        if twin_namespace is not None:
            # a shadow run: the twin's output is known in advance, so it is recorded from its
            # first message instead of from whenever the graph scan finds it (late under load)
            outputs = node_role("twin").topic_types(twin_namespace)
            # (its packed outputs: beside a LinuxCNC bridge only, recorded by _record_bridge)
            known.update({t: k for t, k in outputs.items() if k != msg_types.RECORD_BATCH})
        if LINUXCNC_NODE in options.peers:
            for topics in served:
                self._record_bridge(topics, known)
        for prefix, topics in options.axis_topics().items():
            for role in (SIM_NODE, CONTROLLER_NODE):
                # only a sim or controller node packs: the topics of other producers (a
                # stand-in's joint states) are recorded from the topics themselves
                if record_batch and f"{prefix}{role}" in options.peers:
                    self._record_batched(topics, role, known, record_batch)
        for topic, type_name in known.items():
            self._record(topic, type_name, qos_for.get(topic, DATA_QOS))
        self.create_timer(SCAN_PERIOD_S, self._scan, clock=self.wall)
        self.create_timer(0.05, self._drain_check, clock=self.wall)
        self.start_heartbeat()

    def _record(self, topic: str, type_name: str, qos: QoSProfile) -> None:
        if topic in self._recorded:
            return
        self.bag.add_topic(topic, type_name, qos=(_bag_qos(qos),))
        subscription = self._data_node.create_subscription(
            message_class(type_name), topic, _never_called, qos, raw=True
        )
        self._recorded[topic] = subscription
        if topic.endswith(TWIN_STATE_SUFFIX):
            self._twin_states.add(topic)
        counts = topic not in self._heartbeats  # heartbeats go on while peers live
        live = self.live if self.live is not None and self.live.wants(topic) else None
        self._takers.append((topic, subscription, counts, self._check(topic, type_name), live))

    def _check(self, topic: str, type_name: str) -> Check | None:
        """How `topic`'s messages are told to be the run's (None: they cannot be)."""
        if topic in self._open_topics or not self.auth.enabled:
            return None
        if type_name in SIGNED_TYPES:
            return functools.partial(self._admit_recorded, topic)
        if type_name == msg_types.STRING:
            return functools.partial(self._admit_string, topic)
        return None

    def _admit_recorded(self, topic: str, data: bytes) -> bytes | None:
        # the recording's own verifiers: the node's hear run_state (and may hear more) too,
        # and each message passes a verifier once
        body = self._record_auth.verify(topic, data)
        if body is None:
            self.refuse_foreign(topic, self._record_auth.last_refusal(topic))
        return body

    def _admit_string(self, topic: str, data: bytes) -> bytes | None:
        try:
            (text,) = STRING.decode(data)
        except (ValueError, UnicodeDecodeError, struct.error):
            self.refuse_foreign(topic, "malformed")
            return None
        body = self._record_auth.verify_text(topic, text)
        if body is None:
            self.refuse_foreign(topic, self._record_auth.last_refusal(topic))
            return None
        return STRING.encode((body,))

    def _record_batched(
        self, topics: AxisTopics, role: str, known: dict[str, str], record_batch: int
    ) -> None:
        """Record `role`'s packed topics from its RecordBatch (feed_twin.nodeset.record_batch)
        instead of from their own topics; they leave `known`."""
        inner = {topic: known.pop(topic) for topic in topics.batched(role)}
        self._record_packed(topics.record(role), inner, batch_qos(record_batch))

    def _record_bridge(self, topics: AxisTopics, known: dict[str, str]) -> None:
        """Record the LinuxCNC bridge's messages of axis `topics` from its RecordBatches
        (feed_twin/ros/linuxcnc_node.py): command and joint states, and on this node's own axis
        (the bridge's first) the servo samples of every joint."""
        inner = {topic: known.pop(topic) for topic in (topics.command, topics.joint_states)}
        if topics.namespace == self.topics.namespace:
            inner[topics.servo] = msg_types.SERVO_SAMPLE
        self._record_packed(topics.bridge_batch, inner, DATA_QOS)
        # the axis's twin sends its state and residual packed as well (twin_node --batch-topic)
        twin = node_role("twin")
        namespace = f"{topics.namespace}/twin"  # (feed_twin.shadow.replay.twin_namespace)
        types = twin.topic_types(namespace)
        outputs = {twin.topic(namespace, name): "" for name in ("state", "residual")}
        for topic in outputs:
            outputs[topic] = types[topic]
            known.pop(topic, None)
        batch = twin.topic(namespace, "batch")
        self._record_packed(batch, outputs, DATA_QOS)
        self._twin_states.add(batch)  # the twin is there while it publishes its batches

    def _record_packed(self, batch: str, inner: dict[str, str], qos: QoSProfile) -> None:
        """Record topics `inner` (name -> type) from the RecordBatches on `batch` instead of
        from their own topics."""
        for topic, type_name in inner.items():
            self.bag.add_topic(topic, type_name, qos=(_bag_qos(DATA_QOS),))
            self._recorded[topic] = None  # from the batch: the graph scan passes it by
        subscription = self._data_node.create_subscription(
            RecordBatchMsg, batch, _never_called, qos, raw=True
        )
        self._recorded[batch] = subscription
        self._batch_takers.append((batch, subscription, frozenset(inner)))

    def poll(self) -> float | None:
        now = time.monotonic()
        if now >= self._next_drain:
            self._next_drain = now + DRAIN_PERIOD_S
            self._drain()
        return DRAIN_PERIOD_S

    def _drain(self) -> int:
        """Write every message waiting in the data subscriptions; returns how many."""
        write = self.bag.write
        total = 0
        for topic, subscription, counts, check, live in self._takers:
            handle = subscription.handle
            msg_type = subscription.msg_type
            n = 0
            own = 0
            with handle:
                while True:
                    taken = handle.take_message(msg_type, True)
                    if taken is None:
                        break
                    data, info = taken
                    if check is not None:
                        # a foreign message is dropped here: it must not be recorded, nor
                        # hold the recording open after the run
                        data = check(data)
                        if data is None:
                            continue
                    received = info["received_timestamp"]
                    write(
                        topic,
                        data,
                        log_time_ns=received,
                        publish_time_ns=info["source_timestamp"] or received,
                    )
                    if live is not None:
                        live.feed(topic, data)
                    n += 1
                    own += counts
            if own:
                self._last_message = time.monotonic()
            total += n
        return total + self._drain_batches()

    def _drain_batches(self) -> int:
        """Write every message of the waiting RecordBatches under its own topic."""
        write = self.bag.write
        total = own = 0
        for batch, subscription, allowed in self._batch_takers:
            handle = subscription.handle
            with handle:
                while True:
                    taken = handle.take_message(subscription.msg_type, True)
                    if taken is None:
                        break
                    try:
                        messages = unpack(taken[0])
                    except ValueError as exc:
                        self.get_logger().warning(
                            f"{batch}: a malformed RecordBatch dropped ({exc})",
                            throttle_duration_sec=1.0,
                        )
                        continue
                    for topic, stamp_ns, signed in messages:
                        if topic not in allowed:
                            continue  # only the topics this batch's node publishes
                        data = self._admit_recorded(topic, signed) if self.auth.enabled else signed
                        if data is None:
                            continue
                        # the publish time: a batch arrives up to record_batch exchanges late
                        write(topic, data, log_time_ns=stamp_ns, publish_time_ns=stamp_ns)
                        if self.live is not None and self.live.wants(topic):
                            self.live.feed(topic, data)
                        total += 1
                        own += 1
        if own:
            self._last_message = time.monotonic()
        return total

    def _scan(self) -> None:
        prefix = self._scan_prefix or self.topics.namespace + "/"
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or len(types) != 1:
                continue
            if not (topic.startswith(prefix) or topic in EXTRA_GLOBAL_TOPICS):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            offered = publishers[0].qos_profile
            # discovery does not carry the writer's history depth (it reads 0): a reader as
            # deep as the data topics', or a burst (the twin's output) overflows it and is lost
            qos = QoSProfile(
                depth=max(DATA_QOS.depth, int(offered.depth)),
                reliability=offered.reliability,
                durability=offered.durability,
            )
            try:
                self._record(topic, types[0], qos)
            except (LookupError, ImportError) as exc:
                self.get_logger().warning(f"not recording {topic}: {exc}")

    def on_run_done(self, text: str) -> None:
        self.end_reason = text
        if self._ending_since is None:
            self._ending_since = time.monotonic()

    def on_signal(self, name: str) -> None:
        # The runner stops the producers first: record what they sent before closing the bag.
        self._signal = name
        if self._ending_since is None:
            self._ending_since = time.monotonic()

    def on_peer_lost(self, message: str) -> None:
        # Under load the recorder may lag behind the graph, and a peer that ended normally looks
        # lost until the queued end-of-run message is processed: record what is still in
        # flight first, then decide.
        if self._peer_lost is None:
            self._peer_lost = message
        peers = set(re.findall(r"node '([^']+)' is gone", message)) or {message}
        if peers - self._peers_lost:
            # every lost peer is named: after a stall of this node several may be due at once
            self._peers_lost |= peers
            self.get_logger().warning(f"{message}; recording what is still in flight")
        if self._ending_since is None:
            self._ending_since = time.monotonic()

    def _drain_check(self) -> None:
        if self.bag.error is not None and not self.done:
            # A full disk: stop here; the runner recovers what was flushed and says so.
            self.finish(EXIT_ERROR, f"recorder: recording stopped: {self.bag.error}")
            return
        if self._ending_since is None or self.done:
            return
        now = time.monotonic()
        quiet = now - self._last_message > DRAIN_QUIET_S and not self._twin_still_deciding()
        if quiet or now - self._ending_since > DRAIN_MAX_S:
            if self._signal is not None:
                self.finish(EXIT_SIGNAL, f"stopped by {self._signal}")
            elif self.run_ended or self._peer_lost is None:
                self.finish(EXIT_OK, "")
            else:
                self.finish(EXIT_PEER_LOST, self._peer_lost)

    def _twin_still_deciding(self) -> bool:
        # A shadow twin decides its last samples only once its inputs have been quiet, and
        # under load that can come after the recorder's own quiet period: wait for it to leave.
        # A killed twin stays in the graph until its lease ends: not after a signal or a lost peer.
        if self._signal is not None or self._peer_lost is not None:
            return False
        return any(self.count_publishers(topic) > 0 for topic in self._twin_states)

    def on_shutdown(self, reason: str) -> None:
        self._drain()
        if self.live is not None:
            self.live.close()
        try:
            info = self.bag.close()
        except BagError as exc:
            print(f"recorder: {exc} ({self.bag.dropped} messages not written)", file=sys.stderr)
            return
        print(
            f"recorder: {info.message_count} messages on {len(info.topics)} topics -> "
            f"{self.bag_path}",
            file=sys.stderr,
        )

    def destroy_node(self) -> None:
        self._data_node.destroy_node()
        super().destroy_node()


def _never_called(data: bytes) -> None:
    """The data subscriptions are drained, not spun."""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--bag", required=True, type=Path, help="bag directory to create")
    parser.add_argument("--live-url", default=None, help="Rerun gRPC URL to stream to")
    parser.add_argument(
        "--twin-namespace",
        default=None,
        help="record a shadow twin's state, residual and health topics under this namespace "
        "from the start (other topics of the machine's namespace are found by a graph scan)",
    )


def build(args: argparse.Namespace, ros, options: NodeOptions, context) -> RecorderNode:
    return RecorderNode(
        options,
        args.bag,
        live_url=args.live_url,
        twin_namespace=args.twin_namespace,
        record_batch=ros.record_batch,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    return node_main(argv, prog="recorder node", configure=configure, build=build)


if __name__ == "__main__":
    sys.exit(main())
