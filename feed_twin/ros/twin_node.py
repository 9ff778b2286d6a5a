"""The shadow twin as a ROS 2 node, beside a real axis (or the stand-in node).

Subscribes (raw CDR, decoded with feed_twin.shadow.bagstreams) to the machine's command and
measured topics named by a column map, the same file the replay and the discrepancy workflow
read (`<topic>:<field>` and units; command AxisCommand, measured JointState as ros2_control's
joint_state_broadcaster publishes it, or AxisFeedback). Every message goes into the pure core
`ShadowTwin` by the machine's stamp; after each message the twin advances over what is decided
and publishes, per slot, under `--out-namespace` (default `<command namespace>/twin`):

- `state` (AxisState): the twin's predicted position, setpoint and following error (and i_q
  when the effort is a current);
- `residual` (TwinResidual): measured vs twin following error and effort, deviations, rolling
  RMS;
- `health` (HealthStatus): every verdict; WARN/ERROR also go to the log with the named effect.

`--batch-topic` (the LinuxCNC bridge, feed_twin/ros/linuxcnc_node.py): the command and measured
messages come packed in RecordBatches on that topic (feed_twin.nodeset.record_batch), each as
on its own topic; the twin takes a whole batch per wake-up and advances over it at once, and
sends its state and residual packed too, one RecordBatch per step on `<out namespace>/batch`
(the bridge reads the residuals' stamps from it, the recorder writes each message under its own
topic): at 1 kHz two messages a period to two readers were most of the twin's and the bridge's
per-message work. Health verdicts stay on their topic.

`--rrd` / `--rerun-url` feed the shadow dashboard (feed_twin.shadow.dashboard). At the end of
the run (run_state "done", a signal, or `--max-time`) the node processes what is left and
prints `SHADOW {json}` on stderr: fault counts, the last verdict and the lag of its output
behind the arrival of each measured sample (p50/p99/max, wall clock).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, AxisState, HealthStatus, TwinResidual
from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from sensor_msgs.msg import JointState

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.io.measured import load_column_map
from feed_twin.nodeset.record_batch import RecordBatch, unpack
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.topics import Topic
from feed_twin.ros.dds import DATA_QOS, apply_nice
from feed_twin.ros.runtime import EXIT_OK, PEER_TIMEOUT_S, FeedTwinNode, NodeOptions, start_node
from feed_twin.shadow.bagstreams import MessageFields, plan
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.health import Verdict
from feed_twin.shadow.replay import health_values, twin_namespace
from feed_twin.shadow.twin import ResidualBlock, ShadowTwin

MESSAGE_TYPES = {
    msg_types.AXIS_COMMAND: AxisCommand,
    msg_types.AXIS_FEEDBACK: AxisFeedback,
    msg_types.JOINT_STATE: JointState,
}
DRAIN_QUIET_S = 0.5  # [s] without messages after the run's end before the node finishes
FINAL_AFTER_S = 0.1  # [s] without messages after the run's end: the streams have ended
# [s] measured samples are paired and the twin advanced at most this often: a twin that fell
# behind (messages queued) advances a whole batch per wake-up with its compiled engine instead of
# one sample per message, which is how it catches up; poll() steps what waits in between.
# A step has a fixed cost (pairing, the health checks, the packed output, the dashboard: numpy
# calls on short arrays): 128 us of CPU per 1 ms period stepping every 2 periods, 38 us every
# 10, 33 us every 20 (benchmarks/twin_step_cost.py); beside LinuxCNC, stepping every 2 ms, the
# twin took 140 us a period (perf) and fell seconds behind on a busy host. 10 ms adds at most
# 10 ms to the twin's output latency.
STEP_EVERY_S = 0.01
OUT_BATCH_SAMPLES = 200  # slots in one packed output at most (--batch-topic)
LAG_SAMPLES = 600_000  # lags kept for the report (10 min at 1 kHz): bounded memory
STATE = FlatCodec(msg_types.AXIS_STATE)
RESIDUAL = FlatCodec(msg_types.TWIN_RESIDUAL)
HEALTH = FlatCodec(msg_types.HEALTH_STATUS)


def _rss_mb() -> float:
    """Resident memory of this process [MiB] (Linux /proc)."""
    import os

    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@dataclass(frozen=True, kw_only=True)
class InputTopic:
    """A machine topic the twin subscribes to and the decoder of its mapped fields."""

    topic: Topic
    fields: MessageFields


class TwinNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        *,
        shadow: ShadowTwin,
        command: InputTopic,
        measured: InputTopic,
        out_namespace: str,
        axis_label: str,
        dashboard=None,
        max_time_s: float | None = None,
        batch_topic: str | None = None,
        context=None,
    ) -> None:
        """`batch_topic`: take command and measured messages packed there (module docstring)
        instead of from their own topics."""
        super().__init__("twin", options, context=context)
        self.shadow = shadow
        self.axis_label = axis_label
        self.dashboard = dashboard
        self.max_time_s = max_time_s
        self._cmd_fields = command.fields
        self._meas_fields = measured.fields
        # the measured stream's effort signal, if mapped
        self._effort_name = next(
            (n for n in measured.fields.signal_names if n != "pos_meas_m"), None
        )
        self._is_current = shadow.twin.effort_unit == "A"
        self._state = STATE.fixed({"header.frame_id": "", "axis": axis_label})
        self._residual = RESIDUAL.fixed({"header.frame_id": "", "axis": axis_label})
        for layout in (self._state, self._residual):
            if layout.numbers[:2] != ("header.stamp.sec", "header.stamp.nanosec"):
                raise ValueError(f"{layout.codec.type_name}: the stamp is not its first numbers")
        out = node_role("twin").topic
        self._state_topic = out(out_namespace, "state")
        self._residual_topic = out(out_namespace, "residual")
        # beside the LinuxCNC bridge (--batch-topic) the outputs go out packed as well
        self._packed: RecordBatch | None = None
        if batch_topic is None:
            self._state_pub = self.create_publisher(AxisState, self._state_topic, DATA_QOS)
            self._residual_pub = self.create_publisher(TwinResidual, self._residual_topic, DATA_QOS)
            outputs = [self._state_pub, self._residual_pub]
        else:
            self._packed = RecordBatch([self._state_topic, self._residual_topic], 1)
            self._batch_pub = self.create_publisher(
                RecordBatchMsg, out(out_namespace, "batch"), DATA_QOS
            )
            outputs = [self._batch_pub]
        self._health_pub = self.create_publisher(
            HealthStatus, out(out_namespace, "health"), DATA_QOS
        )
        self._command_topic, self._measured_topic = command.topic.name, measured.topic.name
        watched = measured.topic
        if batch_topic is None:
            for source, callback in ((command, self._on_command), (measured, self._on_measured)):
                topic = source.topic
                self.create_subscription(
                    MESSAGE_TYPES[topic.type_name], topic.name, callback, DATA_QOS, raw=True
                )
        else:
            self.create_subscription(
                RecordBatchMsg, batch_topic, self._on_batch, DATA_QOS, raw=True
            )
            watched = Topic(name=batch_topic, type_name=msg_types.RECORD_BATCH)
        self._seen_command = False
        self._measured_dog = self.watch_input(
            watched.name,
            watched.type_name,
            armed=lambda: self._seen_command and not self.run_ended,
        )
        self._arrival: dict[int, float] = {}
        self._draining_since: float | None = None
        self._final_done = False
        self._last_message = time.monotonic()
        self.lags_ms: deque[float] = deque(maxlen=LAG_SAMPLES)
        self.samples = 0
        self._waiting_for_command = False  # measured samples are there, not yet paired
        self._stepped_at = 0.0  # [s] monotonic time of the last step
        self._unstepped = False  # samples arrived since the last step
        self.errors = 0
        self._rss_start = _rss_mb()
        outputs.append(self._health_pub)
        self.start_heartbeat(when=lambda: self.recorder_listens(outputs))

    def _on_command(self, data: bytes) -> None:
        self._take_command(data)
        if self._waiting_for_command:
            self._step()

    def _on_measured(self, data: bytes) -> None:
        self._take_measured(data)
        self._measured_dog.feed()
        if self._last_message - self._stepped_at >= STEP_EVERY_S:
            self._step()

    def _on_batch(self, data: bytes) -> None:
        self._measured_dog.feed()
        try:
            messages = unpack(data)
        except ValueError as exc:
            self._bad(exc)
            return
        if messages:  # for the trace: how long ago the bridge packed the batch [us]
            now = time.monotonic_ns()
            self.trace.add("batch_age", now, now, (time.time_ns() - messages[0][1]) // 1000)
        for topic, _, message in messages:
            if topic == self._command_topic:
                self._take_command(message)
            elif topic == self._measured_topic:
                self._take_measured(message)
        if self._unstepped and self._last_message - self._stepped_at >= STEP_EVERY_S:
            self._step()

    def _take_command(self, data: bytes) -> None:
        if self.auth.enabled:  # a run's twin: only the run's NC (a bare shadow: any stream)
            admitted = self.admit(self._command_topic, data)
            if admitted is None:
                return
            data = admitted
        self._seen_command = True
        self._last_message = time.monotonic()
        try:
            t, v = self._cmd_fields(data)
        except ValueError as exc:
            self._bad(exc)
            return
        # the twin advances when a measured sample arrives (nothing can be paired earlier);
        # processing on every command too would double the per-cycle work for nothing, but a
        # measured sample that came before its command (transport jitter, a late-joining
        # command stream) waits for this one (_on_command)
        self.shadow.push_command(t, v["pos_cmd_m"], v.get("vel_cmd_m_s"))

    def _take_measured(self, data: bytes) -> None:
        if self.auth.enabled:
            admitted = self.admit(self._measured_topic, data)
            if admitted is None:
                return
            data = admitted
        arrived = time.perf_counter()
        self._last_message = time.monotonic()
        try:
            t, v = self._meas_fields(data)
        except ValueError as exc:
            self._bad(exc)
            return
        effort = v.get(self._effort_name, math.nan) if self._effort_name else math.nan
        outcome = self.shadow.push_measured(t, v["pos_meas_m"], effort)
        if outcome in ("accepted", "reordered"):
            self._arrival[self.shadow.measured.slot_of(t)[0]] = arrived
        self._unstepped = True

    def _bad(self, exc: Exception) -> None:
        self.errors += 1
        if self.errors <= 5:
            self.get_logger().error(f"undecodable message dropped: {exc}")

    def _step(self, *, final: bool = False) -> None:
        self._stepped_at = time.monotonic()
        self._unstepped = False
        self.progressed()
        with self.trace.span("process"):
            block = self.shadow.process(final=final)
        if block is not None and len(block):
            with self.trace.span("publish", len(block)):
                self._publish(block)
        self._waiting_for_command = self.samples < self.shadow.measured.counts.accepted
        for verdict in self.shadow.new_verdicts:
            with self.trace.span("verdict", verdict.level):
                self._verdict(verdict)
        period = self.shadow.config.sample_period_s
        if self.max_time_s is not None and self.samples * period >= self.max_time_s:
            self.finish(EXIT_OK, f"twin: {self.max_time_s:g} s shadowed")

    def _publish(self, b: ResidualBlock) -> None:
        """Each slot's state and residual, packed with the run's fixed strings (one struct
        call each: encoding them field by field was a third of the twin's CPU at 1 kHz)."""
        n = len(b)
        period = self.shadow.config.sample_period_s
        t0 = self.shadow.commands.t0_s or 0.0
        stamps = np.round(b.t_s * 1e9).astype(np.int64)
        sec, nsec = np.divmod(stamps, 1_000_000_000)
        fe_twin = b.x_cmd_m - b.x_twin_m
        state = np.zeros((n, len(self._state.numbers) - 2))  # the numbers after the stamp
        columns = {"position_setpoint": b.x_cmd_m, "table_position": b.x_twin_m,
                   "following_error": fe_twin}  # fmt: skip
        if self._is_current:
            columns["i_q"] = b.effort_twin
        for name, values in columns.items():
            state[:, self._state.index(name) - 2] = values
        residual = np.zeros((n, len(self._residual.numbers) - 2))
        for name, values in {
            "following_error_measured": b.x_cmd_m - b.x_meas_m,
            "following_error_twin": fe_twin,
            "following_error_deviation": b.fe_dev_m,
            "effort_measured": b.effort_meas,
            "effort_twin": b.effort_twin,
            "effort_deviation": b.effort_dev,
            "rms_window": self.shadow.config.window_s,
            "following_error_deviation_rms": b.fe_dev_rms_m,
            "effort_deviation_rms": b.effort_dev_rms,
        }.items():
            residual[:, self._residual.index(name) - 2] = values
        sign = self.auth.sign
        state_topic, residual_topic = self._state_topic, self._residual_topic
        rows = zip(sec.tolist(), nsec.tolist(), state.tolist(), residual.tolist(),
                   b.t_s.tolist(), strict=True)  # fmt: skip
        for s, ns, state_row, residual_row, t in rows:
            self._send(
                sign(state_topic, self._state.encode((s, ns, *state_row))),
                sign(residual_topic, self._residual.encode((s, ns, *residual_row))),
            )
            arrived = self._arrival.pop(round((t - t0) / period), None)
            if arrived is not None:
                self.lags_ms.append((time.perf_counter() - arrived) * 1e3)
        self._flush()
        self.samples += n
        if self.dashboard is not None:
            with self.trace.span("dashboard", n):
                self.dashboard.log_block(b)

    def _send(self, state: bytes, residual: bytes) -> None:
        """One slot's state and residual: on their topics, or packed (OUT_BATCH_SAMPLES at
        most to a RecordBatch, so that a catch-up goes out in pieces)."""
        if self._packed is None:
            self._state_pub.publish(state)
            self._residual_pub.publish(residual)
            return
        now_ns = time.time_ns()
        self._packed.add(0, state, now_ns)
        self._packed.add(1, residual, now_ns)
        if len(self._packed) >= 2 * OUT_BATCH_SAMPLES:
            self._flush()

    def _flush(self) -> None:
        data = None if self._packed is None else self._packed.take()
        if data is not None:
            self._batch_pub.publish(data)

    def _verdict(self, v: Verdict) -> None:
        health = HEALTH.encode(health_values(HEALTH.names, v, self.axis_label))
        self._health_pub.publish(self.auth.sign(self._health_pub.topic_name, health))
        text = f"health {v.level_name} at t = {v.t_s:.3f} s: {v.message}"
        # one call site per severity: rclpy refuses a call site whose severity changes
        if v.level == 2:
            self.get_logger().error(text)
        elif v.level != 0:
            self.get_logger().warning(text)
        if self.dashboard is not None:
            self.dashboard.log_verdict(v)

    def report(self) -> dict:
        lags = np.asarray(self.lags_ms)
        last = self.shadow.health.last
        tenth = max(1, len(lags) // 6)
        return {
            "samples": self.samples,
            "effort_unit": self.shadow.twin.effort_unit,
            "rss_mb": {"start": self._rss_start, "end": _rss_mb()},
            # median lag over the first and the last sixth of the run: a twin that does not
            # keep up shows a growing lag
            "lag_ms_first_p50": float(np.median(lags[:tenth])) if lags.size else None,
            "lag_ms_last_p50": float(np.median(lags[-tenth:])) if lags.size else None,
            "faults": self.shadow.counts(),
            "undecodable": self.errors,
            "lag_ms": {
                "p50": float(np.percentile(lags, 50)) if lags.size else None,
                "p99": float(np.percentile(lags, 99)) if lags.size else None,
                "max": float(lags.max()) if lags.size else None,
                "count": int(lags.size),
            },
            "verdicts": len(self.shadow.health.verdicts),
            "warnings": sum(1 for v in self.shadow.health.verdicts if v.level in (1, 2)),
            "last": None
            if last is None
            else {
                "t_s": last.t_s,
                "level": last.level_name,
                "effect": last.effect,
                "relative_change": last.relative_change,
                "message": last.message,
            },
        }

    def on_run_done(self, text: str) -> None:
        # run_state may overtake the last data messages: drain until the streams are quiet
        self._draining_since = time.monotonic()

    def poll(self) -> float | None:
        if self._unstepped and not self.done:
            wait = self._stepped_at + STEP_EVERY_S - time.monotonic()
            if wait > 0.0:
                return wait
            self._step()
        if self._draining_since is not None and not self.done:
            quiet = time.monotonic() - max(self._last_message, self._draining_since)
            if quiet > FINAL_AFTER_S and not self._final_done:
                # the streams have ended: the last slots (whose command differences wait for a
                # next sample) are decided now, while the recorder still drains
                self._final_done = True
                self._step(final=True)
            if quiet > DRAIN_QUIET_S:
                self.finish(EXIT_OK, "")
                return None
            return 0.05
        return None

    def on_shutdown(self, reason: str) -> None:
        if not self._final_done:
            self._step(final=True)
        if self.dashboard is not None:
            self.dashboard.close()
        print("SHADOW " + json.dumps(self.report()), file=sys.stderr, flush=True)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="model YAML with shadow:")
    parser.add_argument("--map", required=True, type=Path, help="column map (topics, units)")
    parser.add_argument("--command-type", default=msg_types.AXIS_COMMAND)
    parser.add_argument("--measured-type", default=msg_types.JOINT_STATE)
    parser.add_argument("--out-namespace", help="default: <command namespace>/twin")
    parser.add_argument("--machine", default="cnc", help="namespace of the node (machine)")
    parser.add_argument("--axis", default="x", help="namespace of the node (axis)")
    parser.add_argument("--rrd", type=Path, help="write the shadow dashboard here")
    parser.add_argument("--rerun-url", help="stream the dashboard to this viewer")
    parser.add_argument("--max-time", type=float, help="stop after this many shadowed seconds")
    parser.add_argument("--batch-topic", help="take the command and measured messages packed "
                        "in RecordBatches on this topic (the LinuxCNC bridge's)")  # fmt: skip
    parser.add_argument("--input-timeout", type=float, default=10.0, help="[s]")
    parser.add_argument("--peers", default="", help="comma-separated roles to watch")
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="[s]")
    parser.add_argument("--peer-timeout", type=float, default=PEER_TIMEOUT_S, help="[s]")
    parser.add_argument("--nice", type=int, default=0, help="nice value of the process "
                        "(beside LinuxCNC: ros.linuxcnc_nice)")  # fmt: skip


def build(args: argparse.Namespace, context) -> TwinNode:
    cmap = load_column_map(args.map)
    groups = plan(cmap)
    doc = ModelDoc.load(args.config)
    config = load_shadow_config(args.config)
    twin = Twin.compile(doc)
    shadow = ShadowTwin(
        twin,
        config,
        command_velocity="vel_cmd_m_s" in groups["command"],
        travel_m=cmap.plausibility.travel_m,
        effort_sample=cmap.effort_sample,
        measured_effort=any(n != "pos_meas_m" for n in groups["measured"]),
    )
    # compile before the first heartbeat: the engine's first advance loads the kernel
    twin.engine.advance(1)
    twin.engine.reset()
    for kind, type_name in (("command", args.command_type), ("measured", args.measured_type)):
        if type_name not in MESSAGE_TYPES:
            raise ValueError(
                f"--{kind}-type {type_name!r}: one of {', '.join(sorted(MESSAGE_TYPES))}"
            )
    topic_of = {k: next(iter(g.values()))[0].partition(":")[0] for k, g in groups.items()}
    dashboard = None
    if args.rrd is not None or args.rerun_url is not None:
        from feed_twin.shadow.dashboard import ShadowDashboard

        dashboard = ShadowDashboard(
            effort_unit=twin.effort_unit, rrd_path=args.rrd, live_url=args.rerun_url
        )
    node = TwinNode(
        NodeOptions(machine=args.machine, axis=args.axis,
                    peers=tuple(p for p in args.peers.split(",") if p),
                    input_timeout_s=args.input_timeout, startup_timeout_s=args.startup_timeout,
                    peer_timeout_s=args.peer_timeout),
        shadow=shadow,
        command=InputTopic(
            topic=Topic(name=topic_of["command"], type_name=args.command_type),
            fields=MessageFields(args.command_type, groups["command"], cmap),
        ),
        measured=InputTopic(
            topic=Topic(name=topic_of["measured"], type_name=args.measured_type),
            fields=MessageFields(args.measured_type, groups["measured"], cmap),
        ),
        out_namespace=args.out_namespace or twin_namespace(topic_of["command"]),
        axis_label=args.axis.upper(),
        dashboard=dashboard,
        max_time_s=args.max_time,
        batch_topic=args.batch_topic,
        context=context,
    )  # fmt: skip
    apply_nice(node, args.nice)
    return node


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="twin node", description=__doc__.splitlines()[0] if __doc__ else None
    )
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("twin node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
