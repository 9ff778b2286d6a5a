"""What every feed_twin node shares: liveness, input watchdogs, and the spin loop.

- Liveness: each node publishes a heartbeat (its role, process id, host and how many times its
  own loop has turned) every 0.1 s of wall time on `/<machine>/<axis>/heartbeat` and watches its
  peers' heartbeats. A peer is judged on its progress (feed_twin.nodeset.liveness): one whose
  beats stop for `peer_timeout_s` (0.8 s) is gone when its process is dead: the node names it
  and stops with exit code `EXIT_PEER_LOST`; one that makes no progress for longer than the
  tolerance (the floor `peer_timeout_s`, more when this host has been stalling the node's own
  threads) while its process lives is slow: said once, the run goes on, up to `hung_s`. A peer
  never seen within `startup_timeout_s` is reported as not started.
  Heartbeats begin only after a node's set-up (numba compilation included), so a slow start is
  not mistaken for a crash, and (with `start_heartbeat(when=...)`) only once the recorder
  listens to the node's data topics, so that no run starts before its bag can hold everything.
  They are sent and received by a separate small node on its own thread (`Liveness`), so a
  backlog on the data path does not look like a dead peer.
- Input watchdogs: a node that waits for messages on a topic reports, after a timeout, what the
  graph offers instead (the same type on other topics, or the topic with another type), which
  is what goes wrong when a real command stream is wired to the wrong namespace.
- Spinning: rclpy's EventsExecutor is several times faster than the default executor here, but
  its `spin()` busy-loops and ignores SIGTERM, and each `spin_once` call costs 25-30 us of set-up
  even with nothing to do (one call per message made it the largest cost of a lockstep
  exchange). `spin_nodes` therefore runs `spin_until_future_complete` on a future that never
  completes, with the nodes' `poll()` deadline as its timeout: callbacks are dispatched inside
  one call until the timeout; between calls it handles SIGINT/SIGTERM itself, letting every
  node finish cleanly (the recorder closes its bag).
- DDS and process set-up (transport, QoS, scheduling) live in `dds.py`.
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import functools
import gc
import inspect
import math
import os
import resource
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.experimental.events_executor import EventsExecutor
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import String

from feed_twin.nodeset.auth import RunAuth, key_from_environ
from feed_twin.nodeset.foreign import ForeignLedger, foreign_publisher_text, merge
from feed_twin.nodeset.liveness import (
    HEARTBEAT_PERIOD_S,
    HUNG_S,
    Beat,
    JitterMeter,
    PeerState,
    heartbeat_text,
    parse_heartbeat,
    verdict,
)
from feed_twin.nodeset.topics import RECORDER_NODE, AxisTopics
from feed_twin.nodeset.turn_trace import NO_TRACE, NoTrace, TurnTrace, trace_from_environ
from feed_twin.ros.dds import HEARTBEAT_QOS, LATCHED_QOS, init_context
from feed_twin.ros.exit_timer import exit_after

FOREIGN_GRAPH_S = 0.5  # [s] between two looks for the publishers of a topic with refusals
EXIT_OK = 0
EXIT_ERROR = 1  # a configuration, program or runtime error; the message says which
EXIT_PEER_LOST = 3  # another node of the set disappeared
EXIT_INPUT_TIMEOUT = 4  # an expected topic stayed silent
EXIT_SIGNAL = 130  # stopped by SIGINT/SIGTERM (after a clean shutdown)

# Before reporting that nobody offers a silent topic's type, the graph is re-read for up to this
# long: a participant whose first announcements were missed is found at its next periodic one
# (Fast DDS: every 3 s), and the report would otherwise miss the publisher it should name.
GRAPH_SETTLE_S = 3.0
LIVENESS_POLL_S = 0.02  # [s] the liveness thread takes heartbeats this often
ACK_WAIT_S = 0.5  # [s] a stopping node waits for its readers to acknowledge its last messages
ACK_WAIT_ALIVE_S = 10.0  # [s] ... when the recorder is alive (it may lag behind on a busy host)
SIGNAL_DRAIN_S = 30.0  # [s] nodes may take after SIGINT/SIGTERM to finish (recorder drain)
# A node process leaves without DDS's teardown after this long: deleting a reliable writer whose
# reader was killed can block for many seconds, and by then outputs are closed and logged.
TEARDOWN_LIMIT_S = 2.0
# [s] after that, the process leaves from outside Python: a teardown that spins in rclpy's events
# executor with the GIL held (a DDS thread waiting for the GIL) stops every Python thread
GIL_HELD_GRACE_S = 1.0
BEATS_MISSED = 4  # a peer this many beat periods silent has stopped beating (not only its loop)
PEER_TIMEOUT_S = 0.8  # noticed within 0.9 s; 0.6 s gave false alarms on a machine at load 9
# Diagnosis: with FEED_TWIN_STALL_DUMP_S=0.5 in its environment, a node whose spin loop does not
# come back within 0.5 s prints every thread's Python stack to its log (faulthandler: it works
# while a C call holds the GIL). It found the shared-memory lock wait (fastdds_profiles.xml).
STALL_DUMP_ENV = "FEED_TWIN_STALL_DUMP_S"
PARENT_PID_ENV = "FEED_TWIN_PARENT_PID"  # set by launch: the runner, whose death ends the node


@dataclass(frozen=True, kw_only=True)
class NodeOptions:
    """Settings every feed_twin node takes from the runner."""

    machine: str
    axis: str
    peers: tuple[str, ...]  # roles whose heartbeat this node watches
    startup_timeout_s: float = 60.0  # [s] wall time for peers to appear
    input_timeout_s: float = 10.0  # [s] wall time an expected topic may stay silent
    # [s] the floor of the tolerance: no beat this long is gone if dead, no progress slow
    peer_timeout_s: float = PEER_TIMEOUT_S
    hung_s: float = HUNG_S  # [s] a peer whose process lives without progress this long is hung
    # A machine's G-code and recorder node serve several axes (feed_twin.machine.nodes): they
    # also beat, watch peers (named `<axis>/<role>`) and wait for the run's end there.
    other_axes: tuple[str, ...] = ()
    command_axes: tuple[str, ...] = ()  # NC axes without nodes: commanded and recorded only

    def __post_init__(self) -> None:
        for name in ("startup_timeout_s", "input_timeout_s", "peer_timeout_s", "hung_s"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(f"{name} = {value!r}: must be > 0")
        for axis in (*self.other_axes, *self.command_axes):
            AxisTopics(machine=self.machine, axis=axis)  # a valid ROS name
        if self.axis in self.other_axes:
            raise ValueError(f"other_axes = {self.other_axes!r}: names this node's own axis")

    @property
    def topics(self) -> AxisTopics:
        return AxisTopics(machine=self.machine, axis=self.axis)

    def axis_topics(self) -> dict[str, AxisTopics]:
        """Peer-name prefix ('' for this node's namespace, else '<axis>/') -> that axis's
        topics, for every axis with nodes this node serves."""
        return {
            "": self.topics,
            **{f"{a}/": AxisTopics(machine=self.machine, axis=a) for a in self.other_axes},
        }

    def peer_path(self, peer: str) -> str:
        """The full name of peer `peer` (`sim` here, `y/sim` on another axis)."""
        if "/" in peer:
            return f"/{self.machine}/{peer}"
        return f"{self.topics.namespace}/{peer}"


@functools.cache
def process_key() -> bytes | None:
    """The run's key (feed_twin.nodeset.auth), read once per process: a node host's nodes
    share it, and its descriptor is closed once read."""
    return key_from_environ(os.environ)


class Liveness:
    """Heartbeats sent and watched from a thread with its own node, without an executor.

    The data path of a node can be busy for a while (a backlog of messages in the recorder, a
    slow callback on a loaded machine); liveness must not depend on it. A second, tiny node
    (`<role>_liveness`) publishes the role and the node's loop turns (`turns`, counted by the
    node's own loop) every HEARTBEAT_PERIOD_S and records when each peer was last heard and when
    its turns last moved, on a daemon thread that wakes every LIVENESS_POLL_S, takes the waiting
    heartbeats itself and measures how late it wakes (`jitter`: this host's stalls).
    No executor: a default executor's Python bookkeeping held the GIL for a
    fraction of a millisecond per heartbeat and delayed the data thread's exchanges (about ten
    missed real-time steps per second), and a second EventsExecutor in the process lost
    heartbeats.
    """

    def __init__(self, role: str, options: NodeOptions, context: Context) -> None:
        self.role = role
        self.options = options
        self.node = Node(f"{role}_liveness", namespace=options.topics.namespace, context=context)
        # heartbeats are signed too: a foreign one must not keep a dead peer "alive"
        self.auth = RunAuth(process_key())
        self.foreign = ForeignLedger()
        served = options.axis_topics()
        self._pubs = [
            (t.heartbeat, self.node.create_publisher(String, t.heartbeat, HEARTBEAT_QOS))
            for t in served.values()
        ]
        self._subs = [
            (
                prefix,
                t.heartbeat,
                self.node.create_subscription(String, t.heartbeat, _never_called, HEARTBEAT_QOS),
            )
            for prefix, t in served.items()
        ]
        self._lock = threading.Lock()
        self._seen: dict[str, float] = {}
        self._moved: dict[str, float] = {}  # when each peer's turns were last heard to move
        self._beats: dict[str, Beat] = {}  # the latest beat of each peer (its process)
        self.jitter = JitterMeter()  # guarded by _lock: both of the node's threads feed it
        self.turns = 0  # the node's loop turns (an int: set by one thread, read by another)
        self.waiting = False  # the node's loop is in a wait it knows of (FeedTwinNode.waiting)
        self._beating = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"{role}-liveness", daemon=True)
        self._thread.start()

    def start_beating(self) -> None:
        self._beating = True

    @property
    def beating(self) -> bool:
        return self._beating

    def _take(self) -> None:
        for prefix, topic, sub in self._subs:
            handle = sub.handle
            with handle:
                while True:
                    taken = handle.take_message(String, False)
                    if taken is None:
                        break
                    text = self.auth.verify_text(topic, taken[0].data)
                    if text is None:
                        with self._lock:
                            self.foreign.refuse(topic, self.auth.last_refusal(topic))
                        continue
                    beat = parse_heartbeat(text)
                    if beat.role != self.role:
                        self._heard(prefix + beat.role, beat)

    def _heard(self, peer: str, beat: Beat) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._beats.get(peer)
            if last is None or beat.turns is None or beat.turns != last.turns:
                self._moved[peer] = now
            self._seen[peer] = now
            self._beats[peer] = beat

    def _run(self) -> None:
        next_beat = time.monotonic()
        while True:
            before = time.monotonic()
            if self._stop.wait(LIVENESS_POLL_S):
                break
            self.late(before + LIVENESS_POLL_S)
            with contextlib.suppress(Exception):
                self._take()
            now = time.monotonic()
            if self._beating and now >= next_beat:
                next_beat = now + HEARTBEAT_PERIOD_S
                if self.waiting:
                    self.turns += 1  # the loop is not turning, but it waits as it should
                text = heartbeat_text(self.role, self.turns)
                for topic, pub in self._pubs:
                    with contextlib.suppress(Exception):
                        pub.publish(String(data=self.auth.sign_text(topic, text)))

    def late(self, due: float) -> None:
        """A wake-up of one of the node's threads that was due at `due` [s, monotonic]; counted
        from the first beat on (set-up's numba compilation holds the GIL for seconds: that is
        not the host's jitter)."""
        if not self._beating:
            return
        now = time.monotonic()
        with self._lock:
            self.jitter.add(now, now - due)

    def tolerance_s(self) -> float:
        """[s] how long a peer may make no progress before it is slow (from this host's jitter)."""
        with self._lock:
            return self.jitter.tolerance_s(self.options.peer_timeout_s)

    def seen(self) -> dict[str, float]:
        with self._lock:
            return dict(self._seen)

    def peer_state(self, peer: str, now: float) -> PeerState:
        """What is known of `peer` (heard at least once) at `now` [s, monotonic]."""
        with self._lock:
            return PeerState(
                beat=self._beats.get(peer),
                silent_s=now - self._seen[peer],
                still_s=now - self._moved[peer],
            )

    def beat(self, peer: str) -> Beat | None:
        with self._lock:
            return self._beats.get(peer)

    def stop(self) -> None:
        """Stop beating and listening (idempotent); `seen` keeps the last times heard."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=0.5)
        with contextlib.suppress(Exception):
            self.node.destroy_node()


def _never_called(msg: object) -> None:
    """Subscriptions that are taken from directly, never spun."""


class FeedTwinNode(Node):
    """A node with a role, heartbeats, peer watching and a finish state the spin loop reads."""

    def __init__(self, role: str, options: NodeOptions, *, context: Context | None = None):
        super().__init__(
            role,
            namespace=options.topics.namespace,
            context=context,
            start_parameter_services=True,
        )
        self.role = role
        self.options = options
        self.topics = options.topics
        self.exit_code: int | None = None
        self.exit_message = ""
        self.wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._created = time.monotonic()
        self._watchdogs: list[_Watchdog] = []
        self.liveness = Liveness(role, options, self.context)
        # the run's message authentication (feed_twin.nodeset.auth) and what it refused
        self.auth = RunAuth(process_key())
        self.foreign = ForeignLedger()
        # a per-turn timing trace of the loop (feed_twin.nodeset.turn_trace), set by spin_nodes
        self.trace: TurnTrace | NoTrace = NO_TRACE
        self._named_at: dict[str, float] = {}  # topic -> when its publishers were last read
        self._heartbeat_on = False
        self._beat_when: Callable[[], bool] | None = None
        self.setup_cpu_s = 0.0  # CPU time of this process when set-up ended [s]
        self.run_ended = False
        self._slow_since: dict[str, float] = {}  # slow peers (silent, their process lives)
        self.slow_peers: list[str] = []  # every peer said slow during the run
        self._not_done = set(options.axis_topics())  # axes whose sim has not announced the end
        for prefix, topics in options.axis_topics().items():
            self.create_subscription(
                String,
                topics.run_state,
                functools.partial(self._on_run_state, prefix=prefix),
                LATCHED_QOS,
            )
        self._tick_due = time.monotonic() + HEARTBEAT_PERIOD_S
        self.create_timer(HEARTBEAT_PERIOD_S, self._tick, clock=self.wall)

    def start_heartbeat(self, *, when: Callable[[], bool] | None = None) -> None:
        """Call at the end of set-up: peers start watching this node from its first beat.

        With `when`, the first beat waits until when() holds (checked with every liveness
        tick): a producer starts the run only once every peer beats, so a node can hold the
        run back until, for example, the recorder listens to its outputs (`recorder_listens`).
        """
        warm_up_logging()
        self.setup_cpu_s = _cpu_seconds()
        # What set-up built (numba dispatchers, message types, the plant) lives to the end:
        # moved out of the collector's generations, a full collection no longer walks it and
        # cannot stall an exchange for milliseconds.
        gc.collect()
        gc.freeze()
        self._heartbeat_on = True
        self._beat_when = when
        if when is None or when():
            self._beat_when = None
            self.liveness.start_beating()

    def progressed(self) -> None:
        """The node did a piece of its work (a twin's step): progress its beats carry, also
        while the executor, draining a backlog of callbacks, has not come back to the loop
        (a twin that fell behind on a busy host did so for up to 1.9 s, delaying the loop's
        timer 0.46 s: its traces, docs/linuxcnc.md) - catching up is not stalling."""
        self.liveness.turns += 1

    @contextlib.contextmanager
    def waiting(self) -> Iterator[None]:
        """A wait in the node's own loop that the node knows of and bounds itself (another
        run's host lock, a controller's start-up): its beats go on saying progress, so that
        its peers do not take it for slow or hung, and the wait is not counted as jitter."""
        self.liveness.waiting = True
        try:
            yield
        finally:
            self.liveness.waiting = False
            self._tick_due = time.monotonic() + HEARTBEAT_PERIOD_S

    def recorder_listens(self, publishers: Sequence[Any]) -> bool:
        """The recorder's reader is in the graph on every one of `publishers`' topics (True
        when the recorder is not a peer of this node). Transient-local history gives a late
        reader the samples anyway, but not once this node is gone: a run stopped within a
        second of its start lost the twin's whole output that way."""
        if RECORDER_NODE not in self.options.peers:
            return True
        return all(
            any(
                info.node_name.startswith(RECORDER_NODE)  # recorder, recorder_data
                for info in self.get_subscriptions_info_by_topic(pub.topic_name)
            )
            for pub in publishers
        )

    def finish(self, code: int, message: str = "") -> None:
        """Ask the spin loop to stop this node; the first reason wins."""
        if self.exit_code is None:
            self.exit_code = code
            self.exit_message = message
            if message:
                log = self.get_logger().info if code == EXIT_OK else self.get_logger().error
                log(message)

    @property
    def done(self) -> bool:
        return self.exit_code is not None

    def on_shutdown(self, reason: str) -> None:
        """Called once when the node stops (signal, peer loss, end of run); override to clean up."""

    def on_signal(self, name: str) -> None:
        """SIGINT/SIGTERM arrived; by default the node stops at once."""
        self.finish(EXIT_SIGNAL, f"stopped by {name}")

    def on_peer_lost(self, message: str) -> None:
        """A watched peer went silent; by default the node stops with EXIT_PEER_LOST."""
        self.finish(EXIT_PEER_LOST, message)

    def on_run_done(self, text: str) -> None:
        """The sim node announced the end of the run; by default the node stops cleanly."""
        self.finish(EXIT_OK, "")

    def on_run_state(self, text: str) -> None:
        """Any other run_state announcement (the sim's "realtime" at the start); default: none."""

    def admit(self, topic: str, data: bytes) -> bytes | None:
        """A message of the run as its node made it, or None: refused, counted and its
        publisher looked for (feed_twin.nodeset.auth, feed_twin.nodeset.foreign)."""
        body = self.auth.verify(topic, data)
        if body is None:
            self.refuse_foreign(topic, self.auth.last_refusal(topic))
        return body

    def admit_text(self, topic: str, text: str) -> str | None:
        """A text message of the run without its signature, or None (as `admit`)."""
        body = self.auth.verify_text(topic, text)
        if body is None:
            self.refuse_foreign(topic, self.auth.last_refusal(topic))
        return body

    def refuse_foreign(self, topic: str, reason: str) -> None:
        """Count one dropped message; warn on the first of each reason on a topic (a replayed
        or altered message is news even among thousands of unsigned ones) and on every 1000th;
        name the topic's foreign publishers (the graph is read at most every FOREIGN_GRAPH_S
        per topic), each new one in the log too."""
        entry = self.foreign.topics.get(topic)
        new_reason = entry is None or reason not in entry.reasons
        count = self.foreign.refuse(topic, reason)
        if new_reason or count % 1000 == 0:
            self.get_logger().warning(
                f"refused {count} foreign message(s) on {topic} ({reason}): not signed by "
                "this run's nodes"
            )
        now = time.monotonic()
        if now - self._named_at.get(topic, -math.inf) >= FOREIGN_GRAPH_S:
            self._named_at[topic] = now
            for publisher in self.name_foreign(topic):
                self.get_logger().warning(foreign_publisher_text(topic, publisher))

    def name_foreign(self, topic: str) -> list[str]:
        """The publishers of `topic` that are not nodes of the run, added to the ledger;
        returns the ones new to it."""
        from feed_twin.ros.guarded import foreign_publishers

        try:
            found = foreign_publishers(self, topic)
        except Exception:  # noqa: BLE001 - the graph is read again at the next refusal
            return []
        return [p for p in found if self.foreign.name(topic, p)]

    def foreign_record(self) -> ForeignLedger:
        """What this node and its liveness node refused, as one ledger."""
        with self.liveness._lock:
            heartbeats = self.liveness.foreign.as_dict()
        return merge([self.foreign.as_dict(), heartbeats])

    def _on_run_state(self, msg: String, prefix: str = "") -> None:
        topic = self.options.axis_topics()[prefix].run_state
        text = self.admit_text(topic, msg.data)
        if text is None:
            return
        msg = String(data=text)
        if not msg.data.startswith("done"):
            self.on_run_state(msg.data)
            return
        # a machine's run ends when every axis has ended it, or at the first axis's error
        self._not_done.discard(prefix)
        if self._not_done and not msg.data.startswith("done error"):
            return
        if not self.run_ended:
            self.run_ended = True  # peers leave from now on: that is no longer a fault
            self.get_logger().info(f"run state: {msg.data}")
            self.on_run_done(msg.data)

    def poll(self) -> float | None:
        """Called by the spin loop before each wait; returns how long it may block at most [s]
        (None: no limit of its own). Nodes that pace themselves by the wall clock override it."""
        return None

    def watch_input(
        self,
        topic: str,
        type_name: str,
        *,
        armed: Callable[[], bool] = lambda: True,
        timeout_s: float | None = None,
    ) -> _Watchdog:
        """Report after `timeout_s` (default input_timeout_s) of silence on `topic` while
        `armed()` holds."""
        dog = _Watchdog(
            topic=topic,
            type_name=type_name,
            armed=armed,
            timeout_s=self.options.input_timeout_s if timeout_s is None else timeout_s,
        )
        self._watchdogs.append(dog)
        return dog

    def _tick(self) -> None:
        with self.trace.span("tick"):
            self._tick_turn()

    def _tick_turn(self) -> None:
        # This loop's own lateness counts as the host's jitter too: after a stop of the whole
        # process it may run before the liveness thread has measured the stop.
        self.liveness.late(self._tick_due)
        self._tick_due = time.monotonic() + HEARTBEAT_PERIOD_S
        self.liveness.turns += 1
        if self.done:
            return
        if self._beat_when is not None:
            if self._beat_when():
                self._beat_when = None
                self.liveness.start_beating()
            elif time.monotonic() - self._created > self.options.startup_timeout_s:
                self.finish(
                    EXIT_PEER_LOST,
                    f"{self.role} node: the recorder did not subscribe to this node's data "
                    f"topics within {self.options.startup_timeout_s:g} s (it records a topic "
                    "only when it has one type), so the node never joined the run",
                )
                return
        now = time.monotonic()
        heard = self.liveness.seen()
        # the nodes of an axis that has ended its run leave: not a fault (a machine's axes end
        # one after the other)
        watched = [p for p in self.options.peers if _peer_prefix(p) in self._not_done]
        for peer in () if self.run_ended else watched:
            late = now - self._created > self.options.startup_timeout_s
            if peer not in heard and self._heartbeat_on and late:
                self.finish(
                    EXIT_PEER_LOST,
                    f"node '{self.options.peer_path(peer)}' did not start within "
                    f"{self.options.startup_timeout_s:g} s",
                )
        self._judge_peers([p for p in watched if p in heard and not self.run_ended])
        for dog in self._watchdogs:
            if not dog.armed():
                dog.last = now
                continue
            if dog.last is None:
                dog.last = now
            if now - dog.last > dog.timeout_s:
                self.finish(
                    EXIT_INPUT_TIMEOUT,
                    self.describe_silence(dog.topic, dog.type_name, dog.timeout_s),
                )

    def _judge_peers(self, peers: Sequence[str]) -> None:
        """Slow peers said once (and again when they move again), gone or hung ones end the
        node (feed_twin.nodeset.liveness)."""
        now = time.monotonic()
        floor, tolerance = self.options.peer_timeout_s, self.liveness.tolerance_s()
        states = {peer: self.liveness.peer_state(peer, now) for peer in peers}
        verdicts = {
            peer: verdict(state, floor_s=floor, tolerance_s=tolerance, hung_s=self.options.hung_s)
            for peer, state in states.items()
        }
        for peer, said in verdicts.items():
            path = self.options.peer_path(peer)
            if said == "slow" and peer not in self._slow_since:
                self._slow_since[peer] = now - states[peer].still_s
                self.slow_peers.append(path)
                self.get_logger().warning(
                    f"node '{path}' is slow: {_stillness(states[peer], tolerance)}, its process "
                    f"lives (a busy host); the run goes on (hung after {self.options.hung_s:g} s)"
                )
            elif said == "ok" and peer in self._slow_since:
                late = now - self._slow_since.pop(peer)
                self.get_logger().info(f"node '{path}' moves again after {late:.2f} s")
        if not any(v in ("gone", "hung") for v in verdicts.values()):
            return
        # Peers that went silent together (nodes sharing a process, feed_twin.ros.host) are
        # named together: the others beat every 0.1 s, so a few missed beats tell them apart.
        lines = []
        for peer, state in sorted(states.items(), key=lambda item: -item[1].silent_s):
            path = self.options.peer_path(peer)
            if verdicts[peer] == "hung":
                lines.append(
                    f"node '{path}' is hung: {_stillness(state, tolerance)}, its process lives"
                )
            elif verdicts[peer] == "gone" or (
                verdicts[peer] == "ok" and state.silent_s > BEATS_MISSED * HEARTBEAT_PERIOD_S
            ):
                lines.append(f"node '{path}' is gone: no heartbeat for {state.silent_s:.2f} s")
        self.on_peer_lost("; ".join(lines))

    def recorder_alive(self) -> bool:
        """The recorder's heartbeat is recent (it will acknowledge what this node sent)."""
        seen = self.liveness.seen().get("recorder")
        return seen is not None and time.monotonic() - seen < self.options.peer_timeout_s

    def peers_alive(self) -> bool:
        heard = self.liveness.seen()
        return all(p in heard for p in self.options.peers)

    def describe_silence(self, topic: str, type_name: str, timeout_s: float) -> str:
        """Why nothing arrives on `topic`: what the graph offers instead."""
        lines = [f"no {type_name} message on {topic} for {timeout_s:g} s ({self.role} node)"]
        deadline = time.monotonic() + GRAPH_SETTLE_S
        while True:
            offered = [
                (name, types) for name, types in self.get_topic_names_and_types() if name != topic
            ]
            same = [i.topic_type for i in self.get_publishers_info_by_topic(topic)]
            found = same or any(type_name in types for _, types in offered)
            if found or time.monotonic() >= deadline:
                break
            time.sleep(0.05)  # the graph cache fills from the DDS discovery thread
        mistyped = sorted({t for t in same if t != type_name})
        if mistyped:
            lines.append(f"  {topic} is published with type {', '.join(mistyped)} instead")
        elif not same:
            lines.append(f"  nobody publishes {topic}")
        similar = sorted(name for name, types in offered if type_name in types)
        if similar:
            lines.append(f"  {type_name} is published on: {', '.join(similar)} (wrong namespace?)")
        return "\n".join(lines)


def warm_up_logging() -> None:
    """Pay rclpy's first log call now, at set-up. Its logger finds the caller with
    inspect.getframeinfo, whose first call walks every loaded module (a realpath each, about
    2000 modules): 0.25-0.4 s of CPU on this host, seconds when loaded. Paid mid-run it stalled
    the twin's loop at its first health warning and the LinuxCNC bridge's at its first line
    (the bridge latency p99 of a 30 s run rose from about 10 to 215 ms)."""
    frame = inspect.currentframe()
    if frame is not None:
        inspect.getframeinfo(frame)


def _stillness(state: PeerState, tolerance_s: float) -> str:
    """How a peer has made no progress, with the tolerance it went past: its beats stopped
    (more than a few beat periods without one), or only its loop did."""
    how = (
        f"no heartbeat for {state.silent_s:.2f} s"
        if state.silent_s > BEATS_MISSED * HEARTBEAT_PERIOD_S
        else "it beats, its loop does not turn"
    )
    return (
        f"no progress for {state.still_s:.2f} s ({how}; tolerance {tolerance_s:.2f} s from "
        "this host's jitter)"
    )


def _peer_prefix(peer: str) -> str:
    """'y/' for a peer of axis y's namespace, '' for one of the node's own."""
    head, sep, _ = peer.rpartition("/")
    return f"{head}/" if sep else ""


@dataclass
class _Watchdog:
    topic: str
    type_name: str
    armed: Callable[[], bool]
    timeout_s: float
    last: float | None = None

    def feed(self) -> None:
        self.last = time.monotonic()


class _SignalFlag:
    def __init__(self) -> None:
        self.received: int | None = None

    def __call__(self, signum: int, frame: object) -> None:
        self.received = signum


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _spun_enough(
    nodes: Sequence[FeedTwinNode],
    signalled_at: float | None,
    until_all_done: bool,
    stop_on_failure: bool,
) -> bool:
    """Whether `spin_nodes` stops spinning (its docstring)."""
    if signalled_at is not None:
        # After a signal, nodes that drain (the recorder) finish on their own.
        return all(n.done for n in nodes) or time.monotonic() - signalled_at > SIGNAL_DRAIN_S
    if until_all_done:
        failed = stop_on_failure and any(n.exit_code not in (None, EXIT_OK) for n in nodes)
        return failed or all(n.done for n in nodes)
    return any(n.done for n in nodes)


def _shut_down(nodes: Sequence[FeedTwinNode], reason: str) -> None:
    """Every node's `on_shutdown`, its foreign ledger, its heartbeat stopped; then the wait for
    the acknowledgements of what the nodes published."""
    for node in nodes:
        try:
            node.on_shutdown(reason)
        except Exception as exc:  # noqa: BLE001 - one node's cleanup must not skip another's
            print(f"{node.role}: error while shutting down: {exc}", file=sys.stderr)
    for node in nodes:
        ledger = node.foreign_record()
        if ledger.topics:
            print(ledger.log_line(), file=sys.stderr, flush=True)
    # A finished node stops beating: a recorder sharing this process has closed its bag, and
    # the ack wait below (here and in other processes) must not take it for alive.
    for node in nodes:
        node.liveness.stop()
    # Reliable data still in flight (the end-of-run message, the last samples) reaches the
    # recorder only while the writers exist: wait for the acknowledgements while the
    # recorder is alive (it may lag behind on a busy host), briefly once it is gone.
    started = time.monotonic()
    pending = [p for n in nodes for p in n.publishers]
    while pending and time.monotonic() - started < ACK_WAIT_ALIVE_S:
        slice_ = Duration(nanoseconds=50_000_000)
        with contextlib.suppress(Exception):
            pending = [p for p in pending if not p.wait_for_all_acked(slice_)]
        waited = time.monotonic() - started
        if waited > ACK_WAIT_S and not any(n.recorder_alive() for n in nodes):
            break


def spin_nodes(
    nodes: Sequence[FeedTwinNode],
    context: Context,
    *,
    until_all_done: bool = False,
    stop_on_failure: bool = False,
    poll_s: float = 0.02,
    teardown_limit_s: float | None = None,
) -> int:
    """Spin until one node finishes (or all, with until_all_done; with stop_on_failure too,
    at the first node that finishes with a non-zero code) or a signal arrives.

    Every node's `on_shutdown` runs before returning; returns the process exit code (the
    first non-zero code of the nodes, EXIT_SIGNAL after SIGINT/SIGTERM). With
    `teardown_limit_s` (a node process of its own, never a host program), a DDS teardown that
    takes longer ends the process with that code instead.
    """
    flag = _SignalFlag()
    previous = {s: signal.signal(s, flag) for s in (signal.SIGINT, signal.SIGTERM)}
    executor = EventsExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    never = Future()  # spin_until_future_complete then returns at its timeout
    trace = trace_from_environ("+".join(n.role for n in nodes))
    for node in nodes:
        node.trace = trace
    stall_dump_s = float(os.environ.get(STALL_DUMP_ENV) or 0.0)
    signalled_at: float | None = None
    code = EXIT_ERROR  # until the nodes have ended normally
    try:
        while True:
            if flag.received is not None and signalled_at is None:
                signalled_at = time.monotonic()
                name = signal.Signals(flag.received).name
                for node in nodes:
                    node.on_signal(name)
            if _spun_enough(nodes, signalled_at, until_all_done, stop_on_failure):
                break
            trace.turn()
            with trace.span("poll"):
                waits = [w for w in (n.poll() for n in nodes) if w is not None]
            if stall_dump_s > 0.0:
                faulthandler.dump_traceback_later(stall_dump_s, repeat=True)
            with trace.span("spin"):
                executor.spin_until_future_complete(never, timeout_sec=min([poll_s, *waits]))
            if stall_dump_s > 0.0:
                faulthandler.cancel_dump_traceback_later()
        reason = (
            f"stopped by {signal.Signals(flag.received).name}"
            if flag.received is not None
            else next((n.exit_message for n in nodes if n.done and n.exit_message), "")
        )
        _shut_down(nodes, reason)
        written = trace.write()
        if written is not None:
            print(f"turn trace: {written}", file=sys.stderr, flush=True)
        total = _cpu_seconds()
        setup = max(n.setup_cpu_s for n in nodes)
        roles = "+".join(n.role for n in nodes)
        print(
            f"CPU {roles} {total:.2f} s, {total - setup:.2f} s after set-up; ended: "
            f"{reason or 'run done'}; codes {[n.exit_code for n in nodes]}",
            file=sys.stderr,
            flush=True,
        )
        codes = [n.exit_code for n in nodes if n.exit_code not in (None, EXIT_OK)]
        code = EXIT_SIGNAL if flag.received is not None else (codes[0] if codes else EXIT_OK)
        return code
    finally:
        started = time.monotonic()
        if teardown_limit_s is not None:
            exit_if_teardown_hangs(teardown_limit_s, code)
        for node in nodes:
            node.liveness.stop()
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown(timeout_sec=0.2)
        context.try_shutdown()
        print(f"teardown {time.monotonic() - started:.2f} s", file=sys.stderr, flush=True)
        for s, handler in previous.items():
            signal.signal(s, handler)


def exit_if_teardown_hangs(limit_s: float, code: int) -> None:
    """Leave with `code` once the teardown has taken `limit_s`: from a Python thread with a
    line saying so, or, if a C call holds the GIL so that no Python thread runs, silently one
    second later from libc's own timer thread (feed_twin.ros.exit_timer)."""

    def leave() -> None:
        message = f"teardown: DDS did not finish within {limit_s} s; leaving"
        print(message, file=sys.stderr, flush=True)
        os._exit(code)

    timer = threading.Timer(limit_s, leave)
    timer.daemon = True
    timer.start()
    try:
        exit_after(limit_s + GIL_HELD_GRACE_S, code)
    except (OSError, ValueError) as exc:  # the Python timer still covers one without the GIL
        print(f"teardown: no deadline outside Python: {exc}", file=sys.stderr, flush=True)


def node_parser(prog: str, configure: Callable[[argparse.ArgumentParser], None]):
    """The command line of one node process: the common options, then the node's own."""
    parser = argparse.ArgumentParser(prog=prog)
    parser.add_argument("--config", required=True, type=Path, help="axis config (ros section)")
    parser.add_argument("--peers", default="", help="comma-separated roles to watch")
    parser.add_argument("--input-timeout", type=float, default=10.0, help="[s]")
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="[s]")
    parser.add_argument(
        "--peer-timeout", type=float, default=PEER_TIMEOUT_S, help="[s] silence of a lost peer"
    )
    parser.add_argument(
        "--machine-axes", default="", help="further axes with nodes this node serves (a, b)"
    )
    parser.add_argument(
        "--command-axes", default="", help="NC axes without nodes: commanded and recorded only"
    )
    configure(parser)
    return parser


def node_options(args: argparse.Namespace, ros) -> NodeOptions:
    return NodeOptions(
        machine=ros.machine,
        axis=ros.axis,
        peers=tuple(p for p in args.peers.split(",") if p),
        input_timeout_s=args.input_timeout,
        startup_timeout_s=args.startup_timeout,
        peer_timeout_s=getattr(args, "peer_timeout", PEER_TIMEOUT_S),
        other_axes=tuple(a for a in getattr(args, "machine_axes", "").split(",") if a),
        command_axes=tuple(a for a in getattr(args, "command_axes", "").split(",") if a),
    )


def watch_parent(parent_pid: int, *, period_s: float = 0.2) -> threading.Thread:
    """SIGTERM this process once `parent_pid` is no longer its parent (the runner died and the
    process was re-parented): the clean shutdown then runs as for a stop by the runner."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(period_s)
        os.kill(os.getpid(), signal.SIGTERM)

    thread = threading.Thread(target=watch, name="parent-watch", daemon=True)
    thread.start()
    return thread


def start_node(
    prog: str,
    make: Callable[[Any], FeedTwinNode | Sequence[FeedTwinNode]],
    *,
    stop_on_failure: bool = False,
) -> int:
    """Create the ROS context, build the node (or the nodes sharing this process, which then
    runs until all of them have finished, or with `stop_on_failure` until the first fails)
    with `make(context)` and spin it; a bad configuration or input (a ValueError, KeyError or
    OSError) prints one line naming `prog` and returns EXIT_ERROR."""
    parent = os.environ.get(PARENT_PID_ENV)
    if parent is not None and parent.isdigit():
        watch_parent(int(parent))
    context = None
    try:
        context = init_context()
        made = make(context)
    except (ValueError, KeyError, OSError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        if context is not None:
            context.try_shutdown()
        return EXIT_ERROR
    if isinstance(made, FeedTwinNode):
        return spin_nodes([made], context, teardown_limit_s=TEARDOWN_LIMIT_S)
    return spin_nodes(
        made,
        context,
        until_all_done=True,
        stop_on_failure=stop_on_failure,
        teardown_limit_s=TEARDOWN_LIMIT_S,
    )


def node_main(
    argv: Sequence[str] | None,
    *,
    prog: str,
    configure: Callable[[argparse.ArgumentParser], None],
    build: Callable[..., FeedTwinNode],
) -> int:
    """Parse, load the config, build the node with `build(args, ros, options, context)` and
    spin it (`start_node`)."""
    from feed_twin.nodeset.config import load_node_set_config

    args = node_parser(prog, configure).parse_args(argv)

    def make(context) -> FeedTwinNode:
        ros = load_node_set_config(args.config)
        return build(args, ros, node_options(args, ros), context)

    return start_node(prog, make)
