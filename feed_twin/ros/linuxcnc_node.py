"""LinuxCNC as the NC and the machine of the shadow twin: the bridge node.

Runs one program on LinuxCNC (feed_twin.linuxcnc.runner: headless, every 1 kHz servo period)
once its peers are up and the twin listens, and makes three messages of each period (stamps
and pairing: feed_twin.linuxcnc.bridge):

- `<ns>/command` (AxisCommand): LinuxCNC's commanded position, velocity, acceleration and
  program line of the twin's joint, as the G-code node would publish them;
- `<ns>/joint_states` (JointState, position only): that joint's feedback, stamped with the
  period it belongs to, as the stand-in machine publishes it: the twin node shadows LinuxCNC
  unchanged (the HAL servo has no effort, so there is no effort residual);
- `<ns>/linuxcnc/servo` (ServoSample): every joint's command, feedback, following error and
  PID output, for the bag.

They go out packed, each signed for its own topic, in one RecordBatch on `<ns>/linuxcnc/batch`
per look at LinuxCNC's rows (at most BATCH_PERIODS periods): three messages a period, each a
datagram to the twin and one to the recorder, made the bridge's latency p99 reach a second on a
busy host, where every wake-up of a process costs. The twin advances over a whole batch per
wake-up (twin_node --batch-topic); the recorder writes each message under its own topic, so
the bag holds what per-period publishing gave.

Latency (feed_twin.linuxcnc.bridge): servo tick -> published, and servo tick -> the twin's
`<ns>/twin/residual` for that period back at the bridge (in the twin's packed output,
`<ns>/twin/batch`). At the
program's end it announces `done: program finished` on run_state; a LinuxCNC fault (a program it
rejects, LinuxCNC dying, the bridge falling so far behind that LinuxCNC's sampler FIFO would
overflow) ends the run with `done: LinuxCNC fault` and
the fault's one line as the node's exit message, so the twin and the recorder finish and the bag
stays readable. Stderr: `PROGRESS <program time>` and at the end `LINUXCNC {json}` (counts,
latency, LinuxCNC's program time and following error, start-up).
"""

from __future__ import annotations

import argparse
import functools
import json
import struct
import sys
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from rclpy.publisher import Publisher
from std_msgs.msg import String

from feed_twin.io import msg_types
from feed_twin.io.cdr import FixedLayout, FlatCodec
from feed_twin.linuxcnc.bridge import BridgeBatch, ServoBridge
from feed_twin.linuxcnc.host import LinuxcncError
from feed_twin.linuxcnc.machine import machine_for_config
from feed_twin.linuxcnc.runner import LinuxcncRun, RunOptions
from feed_twin.linuxcnc.servo_cdr import ServoSampleLayout
from feed_twin.nodeset.record_batch import RecordBatch, unpack
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS, apply_nice
from feed_twin.ros.runtime import EXIT_ERROR, EXIT_OK, FeedTwinNode, NodeOptions, start_node
from feed_twin.shadow.bagstreams import encode_joint_state
from feed_twin.shadow.replay import twin_namespace

COMMAND = FlatCodec(msg_types.AXIS_COMMAND)
LINGER_S = 1.0  # [s] after the end, so that readers receive everything
# periods published ahead of the twin's output at most: what is in flight between the bridge
# and the twin. It bounds the throughput to WINDOW periods per round trip bridge -> twin ->
# bridge, which takes 0.1-0.3 s on a loaded host: 100 made the twin fall seconds behind
# there, and with 1000 a twin a second behind held the bridge back (bridge latency p99 0.3-0.4
# s at load 14-25). A batch holds at least one period, so WINDOW periods stay inside DATA_QOS's
# history of the batch topic (5000 messages): nothing in flight is dropped.
WINDOW = 4000
# periods in one RecordBatch at most: a catch-up after a stall goes out in pieces of a few tens
# of kB instead of one message of a second's periods
BATCH_PERIODS = 100
LATENCY_BOUND_S = 0.2  # [s] servo tick -> published above this is said once (the run goes on)
PROGRESS_PERIOD_S = 0.5
_STAMP = struct.Struct("<iI")  # header.stamp right after the 4-byte CDR encapsulation
SERVO_JOINTS = ("X", "Y", "Z")  # the joints of every ServoSample (LinuxCNC's joints 0, 1, 2)
TWIN = node_role("twin")
TWIN_NODE = TWIN.node_name


@dataclass(frozen=True, kw_only=True)
class AxisOut:
    """What the bridge sends one shadowed axis: its joint's periods, packed on its batch topic."""

    label: str  # the NC axis, e.g. "X"
    joint: int  # LinuxCNC's joint of that axis
    topics: AxisTopics
    command: FixedLayout  # the axis's AxisCommand
    batch: RecordBatch  # command, joint_states (and servo) of the periods not yet sent
    publisher: Publisher  # on topics.bridge_batch
    servo: bool  # its batch carries the ServoSample of every joint (the first axis's)
    residual: str  # the topic of its twin's residuals, which come packed on the twin's batch


class LinuxcncNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        *,
        start_run: Callable[[], LinuxcncRun],
        joint: int,
        period_s: float,
        latency_bound_s: float = LATENCY_BOUND_S,
        context=None,
    ) -> None:
        super().__init__("linuxcnc", options, context=context)
        self._start_run = start_run
        self.joint = joint
        self.period_s = period_s
        self._label = options.axis.upper()
        self._axes: dict[str, AxisOut] = {}
        self._twin_stamps: dict[str, int] = {}  # per axis the stamp of its twin's latest output
        self.add_axis(self._label, joint, self.topics)
        self._servo = ServoSampleLayout(self._label, SERVO_JOINTS)
        # where the end of the run is announced (a machine's node: every axis's run_state)
        self._run_pubs = [self.create_publisher(String, self.topics.run_state, LATCHED_QOS)]
        self.run: LinuxcncRun | None = None
        self.run_ended = False  # LinuxCNC has been stopped (run is None again)
        self.bridge: ServoBridge | None = None
        self.report: dict = {}
        self._done_at: float | None = None
        self._backlog: deque[list] = deque()  # [batch, first row not yet published]
        self._twin_ns = -1  # stamp of the twin's latest output [ns]
        self._sent_ns: int | None = None  # stamp of the latest published period [ns]
        self._progress_at = 0.0
        self._t_start = 0.0
        self.latency_bound_s = latency_bound_s
        self._latency_said = False
        self.start_heartbeat(
            when=lambda: self.recorder_listens([a.publisher for a in self._axes.values()])
        )

    def add_axis(self, label: str, joint: int, topics: AxisTopics) -> None:
        """Shadow NC axis `label` (LinuxCNC's joint `joint`) on `topics`; the first axis added
        carries the servo samples."""
        command = COMMAND.fixed({"header.frame_id": "", "axis": label})
        if command.numbers != _COMMAND_ORDER:
            raise ValueError(f"AxisCommand's numbers are {command.numbers}")
        servo = not self._axes
        packed = [topics.command, topics.joint_states] + ([topics.servo] if servo else [])
        twin = twin_namespace(topics.command)
        self._axes[label] = AxisOut(
            label=label,
            joint=joint,
            topics=topics,
            command=command,
            batch=RecordBatch(packed, 1),
            publisher=self.create_publisher(RecordBatchMsg, topics.bridge_batch, DATA_QOS),
            servo=servo,
            residual=TWIN.topic(twin, "residual"),
        )
        self._twin_stamps[label] = -1
        self.create_subscription(
            RecordBatchMsg,
            TWIN.topic(twin, "batch"),
            functools.partial(self._on_twin_output, label),
            DATA_QOS,
            raw=True,
        )

    def poll(self) -> float | None:
        if self.done:
            return None
        now = time.monotonic()
        if self._done_at is not None:
            if now - self._done_at > LINGER_S:
                self.finish(*self._ending)
                return None
            return 0.05
        if self.run is None and not self.run_ended:
            if not self._ready():
                return 0.01
            self._t_start = now
            try:
                with self.waiting():  # for another run's host lock, then LinuxCNC's start-up
                    run = self._start_run()
            except LinuxcncError as exc:
                self._end(EXIT_ERROR, str(exc))
                return 0.05
            self.run = run
            self.bridge = ServoBridge(run.layout, period_s=self.period_s, joint=self.joint)
            self.report["startup_s"] = time.monotonic() - now
        if self.run is not None and self.bridge is not None:
            try:
                with self.trace.span("rows"):
                    rows = self.run.poll(0.0)
            except LinuxcncError as exc:
                self._end(EXIT_ERROR, str(exc))
                return 0.05
            with self.trace.span("take", len(rows)):
                batch = self.bridge.take(rows, now_s=time.monotonic())
            if batch is not None:
                self._backlog.append([batch, 0])
            if self.run.ended:
                self._close_run()  # LinuxCNC is done; what it sent may still be waiting here
        self._publish_window()
        if now - self._progress_at > PROGRESS_PERIOD_S and self._sent_ns is not None:
            self._progress_at = now
            print(f"PROGRESS {self._sent_ns * 1e-9:.3f}", file=sys.stderr, flush=True)
        if self.run_ended and not self._backlog:
            self._end(EXIT_OK, "")
            return 0.05
        return 0.001

    def _ready(self) -> bool:
        """LinuxCNC may start: the peers beat, every axis's twin listens, and the recorder."""
        publishers = [a.publisher for a in self._axes.values()]
        return (
            self.peers_alive()
            and all(
                any(i.node_name == TWIN_NODE for i in self.get_subscriptions_info_by_topic(name))
                for name in (p.topic_name for p in publishers)
            )
            and self.recorder_listens(publishers)
        )

    def _publish_window(self) -> None:
        """Publish what waits, at most WINDOW periods ahead of the twin's output: LinuxCNC
        does not wait for a slow twin, this node does (DDS would drop what the twin's reader
        cannot hold), so the twin shadows every period, late if it must."""
        window_end = self._twin_ns + round(WINDOW * self.period_s * 1e9)
        bridge = self.bridge
        while self._backlog and bridge is not None:
            batch, start = self._backlog[0]
            stop = start
            last = min(len(batch), start + BATCH_PERIODS)
            while stop < last and batch.stamp_ns[stop] <= window_end:
                stop += 1
            if stop == start:
                return
            with self.trace.span("publish", stop - start):
                self._publish(batch, start, stop)
            now = time.monotonic()
            bridge.mark_published(batch, start, stop, now_s=now)
            late = now - float(batch.tick_time_s[start])
            if late > self.latency_bound_s and not self._latency_said:
                self._latency_said = True
                self.get_logger().warning(
                    f"the twin shadows LinuxCNC {late * 1e3:.0f} ms late (servo tick -> "
                    f"published; bound {self.latency_bound_s * 1e3:.0f} ms): the run goes on "
                    "and catches up in batches"
                )
            self._sent_ns = int(batch.stamp_ns[stop - 1])
            if stop == len(batch):
                self._backlog.popleft()
            else:
                self._backlog[0][1] = stop

    def _publish(self, b: BridgeBatch, start: int, stop: int) -> None:
        """Periods `start` to `stop` of `b` in one RecordBatch per axis (module docstring)."""
        period_ns = round(self.period_s * 1e9)
        stamps = b.stamp_ns[start:stop].tolist()
        lines = b.line[start:stop].tolist()
        now_ns = time.time_ns()
        sign = self.auth.sign  # the run's signature (feed_twin.nodeset.auth)
        for axis in self._axes.values():
            j, topics, batch = axis.joint, axis.topics, axis.batch
            encode = axis.command.encode
            rows = zip(stamps, b.pos_cmd_m[start:stop, j].tolist(),
                       b.vel_cmd_m_s[start:stop, j].tolist(),
                       b.acc_cmd_m_s2[start:stop, j].tolist(), lines,
                       b.pos_fb_m[start:stop, j].tolist(), strict=True)  # fmt: skip
            joint = [axis.label.lower()]
            for stamp, x, v, a, line, fb in rows:
                sec, nsec = divmod(stamp, 1_000_000_000)
                batch.add(0, sign(topics.command, encode((sec, nsec, x, v, a, line))), now_ns)
                if stamp > 0:  # row k's feedback is period k - 1's (feed_twin.linuxcnc.bridge)
                    js = encode_joint_state(stamp - period_ns, joint, [fb], [], [])
                    batch.add(1, sign(topics.joint_states, js), now_ns)
            if axis.servo:
                self._add_servo(batch, b, start, stop, now_ns)
            data = batch.take()
            if data is not None:
                axis.publisher.publish(data)

    def _add_servo(self, batch: RecordBatch, b: BridgeBatch, start: int, stop: int, now_ns: int):
        topic = batch.topics[2]
        values = np.hstack(
            (b.pos_cmd_m, b.vel_cmd_m_s, b.acc_cmd_m_s2, b.pos_fb_m, b.f_error_m, b.pid_output_m_s)
        )[start:stop].tolist()
        rows = zip(b.stamp_ns[start:stop].tolist(), b.tick[start:stop].tolist(),
                   b.tick_time_s[start:stop].tolist(), b.line[start:stop].tolist(), values,
                   strict=True)  # fmt: skip
        encode, sign = self._servo.encode, self.auth.sign
        for stamp, tick, tick_time, line, row in rows:
            sec, nsec = divmod(stamp, 1_000_000_000)
            servo = encode(sec, nsec, tick, tick_time, max(0, line), row)
            batch.add(2, sign(topic, servo), now_ns)

    def on_run_done(self, text: str) -> None:
        """This node announces the end itself (and hears its own announcement): it finishes
        after LINGER_S with the code of its run, not at the announcement."""

    def _on_twin_output(self, label: str, data: bytes) -> None:
        """Axis `label`'s twin sent its output (packed: twin_node --batch-topic): the window
        follows the slowest twin, none is flooded; the latency is the first axis's."""
        with self.trace.span("twin_output"):
            self._take_twin_output(label, data)

    def _take_twin_output(self, label: str, data: bytes) -> None:
        axis = self._axes[label]
        try:
            stamps = [
                sec * 1_000_000_000 + nsec
                for topic, _, message in unpack(data)
                if topic == axis.residual
                for sec, nsec in (_STAMP.unpack_from(message, 4),)
            ]
        except (ValueError, struct.error) as exc:
            self.get_logger().warning(
                f"{label}: a malformed twin output dropped ({exc})", throttle_duration_sec=1.0
            )
            return
        if not stamps:
            return
        self._twin_stamps[label] = max(self._twin_stamps[label], *stamps)
        self._twin_ns = min(self._twin_stamps.values())
        if axis.servo and self.bridge is not None:
            now = time.monotonic()
            for stamp in stamps:
                self.bridge.twin_output(stamp, now_s=now)

    def _end(self, code: int, message: str) -> None:
        """Stop LinuxCNC, announce the end of the run, stay LINGER_S, then finish."""
        self._close_run()
        text = "done: program finished" if code == EXIT_OK else "done: LinuxCNC fault"
        for pub in self._run_pubs:
            pub.publish(String(data=self.auth.sign_text(pub.topic_name, text)))
        self._ending = (code, message)
        self._done_at = time.monotonic()
        if message:
            self.report["fault"] = message

    def _close_run(self) -> None:
        run, self.run = self.run, None
        self.run_ended = True
        if run is None:
            return
        fault_at = run.fault_wall
        with self.waiting():  # LinuxCNC's shutdown and its trace: about a second, not a stall
            run.__exit__(None, None, None)
            trace = run.trace()
        span = trace.program_span()
        program = trace.cut(span)
        self.report.update(
            program_time_s=program.program_time_s,
            linuxcnc_following_error_max_m=(
                float(np.max(np.abs(program.f_error_m[:, self.joint]))) if program.samples else None
            ),
            sampler_overruns=int((run.state.end or {}).get("overruns", 0)),
            samples_lost_total=trace.samples_lost,
            stop_s=None if fault_at is None else time.monotonic() - fault_at,
            reader_lag_max_s=run.lag_max_s,
        )
        reader = program.reader_latency_s * 1e3
        if reader.size:
            self.report.update(
                reader_latency_p50_ms=float(np.percentile(reader, 50)),
                reader_latency_p99_ms=float(np.percentile(reader, 99)),
            )

    def _expected(self, periods: int) -> dict[str, int]:
        """Messages each topic of the run should hold in the bag, per shadowed axis: one per
        program period on command (and servo), one fewer on joint_states (row k's feedback is
        period k - 1's) and on the twin's output, which shadows every measured sample."""
        measured = max(0, periods - 1)
        out: dict[str, int] = {}
        for axis in self._axes.values():
            twin = twin_namespace(axis.topics.command)
            out[axis.topics.command] = periods
            if axis.servo:
                out[axis.topics.servo] = periods
            out[axis.topics.joint_states] = measured
            out[node_role("twin").topic(twin, "residual")] = measured
            out[node_role("twin").topic(twin, "state")] = measured
        return out

    def on_shutdown(self, reason: str) -> None:
        self._close_run()
        if self.bridge is not None:
            self.report.update(self.bridge.report())
            self.report["expected"] = self._expected(int(self.report["program_periods"]))
        self.report["wall_s"] = time.monotonic() - self._t_start if self._t_start else None
        self.report["latency_bound_ms"] = self.latency_bound_s * 1e3
        self.report["latency_over_bound"] = self._latency_said
        print("LINUXCNC " + json.dumps(self.report), file=sys.stderr, flush=True)


_COMMAND_ORDER = (
    "header.stamp.sec", "header.stamp.nanosec", "position", "velocity", "acceleration", "line",
)  # fmt: skip


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="axis config (nc:, ros:)")
    parser.add_argument("--program", required=True, type=Path, help="G-code program")
    parser.add_argument("--timeout", type=float, default=3600.0, help="[s] program run at most")
    parser.add_argument("--max-lag", type=float, default=1.0,
                        help="[s] bridge lag said once above it (the run goes on)")  # fmt: skip
    parser.add_argument("--peers", default="", help="comma-separated roles to watch")
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="[s]")
    parser.add_argument("--input-timeout", type=float, default=10.0, help="[s]")
    parser.add_argument("--nice", type=int, default=0,
                        help="nice value of the process (ros.linuxcnc_nice)")  # fmt: skip


def run_starter(args: argparse.Namespace, nc, servo) -> Callable[[], LinuxcncRun]:
    """What starts LinuxCNC on the node's program once the node set is up."""
    options = RunOptions(timeout_s=args.timeout, max_lag_s=args.max_lag)

    def start_run() -> LinuxcncRun:
        run = LinuxcncRun(args.program, nc=nc, servo=servo, options=options,
                          say=lambda text: print(text, file=sys.stderr, flush=True))  # fmt: skip
        return run.__enter__()

    return start_run


def build(args: argparse.Namespace, context) -> LinuxcncNode:
    from feed_twin.nodeset.config import load_node_set_config

    ros = load_node_set_config(args.config)
    nc, servo = machine_for_config(args.config)
    node = LinuxcncNode(
        NodeOptions(
            machine=ros.machine,
            axis=ros.axis,
            peers=tuple(p for p in args.peers.split(",") if p),
            startup_timeout_s=args.startup_timeout,
            input_timeout_s=args.input_timeout,
        ),
        start_run=run_starter(args, nc, servo),
        joint=nc.axis_index(nc.twin_axis),
        period_s=servo.servo_period_s,
        context=context,
    )
    apply_nice(node, args.nice)
    return node


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="linuxcnc node", description=__doc__.splitlines()[0] if __doc__ else None
    )
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("linuxcnc node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
