"""The sim node: hosts the plant and the drive's inner loops, publishes what a drive reports.

Per exchange it holds the latest DriveCommand, advances the engine one exchange period
(`drive_host.DriveHost`) and publishes `feedback` (AxisFeedback: sensors as the drive latched
them), `state` (AxisState: the simulated truth), `joint_states` (sensor_msgs/JointState: table
position, velocity and the force the nut applies to it, for standard tools) and `/clock`.

Timing:
- lockstep (default): the next exchange runs as soon as the DriveCommand for it arrives, so the
  run is deterministic and as fast as the graph allows;
- real time: exchanges start at wall-clock instants t0 + k*T; a DriveCommand that has not
  arrived by then counts as a missed step and the previous one is held (as a drive does). At the
  end the node reports lateness p50/p99/max of the exchange starts and the missed steps.

With `ros.record_batch` N > 0 the recorder's copies of feedback, state and joint states go to it
packed, one RecordBatch per N exchanges (feed_twin.ros.batched); the topics carry every message
as before. The run ends `settle_s` after the program has finished (or was stopped), at the
same exchange in every run (feed_twin.nodeset.run_end); the node announces it on `run_state`
("done ..."), which ends the other nodes too.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import operator
import sys
import time
from collections.abc import Sequence

from feed_twin_msgs.msg import AxisFeedback, AxisState, DriveCommand
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from feed_twin.core import signals as sig
from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec, JointStateLayout
from feed_twin.nodeset.drive_host import TRUTH_FIELDS, DriveHost, build_drive_host
from feed_twin.nodeset.guard import bounds_of, check_values, parse_program_state, within_bounds
from feed_twin.nodeset.node_settings import SimSettings
from feed_twin.nodeset.pacing import pacing_report, realtime_announcement
from feed_twin.nodeset.protection import DriveProtection, Trip, protection_for_config
from feed_twin.nodeset.run_end import RunEnd
from feed_twin.nodeset.topics import SIM_NODE
from feed_twin.nodeset.wire import NS_PER_S, DriveSetpoint
from feed_twin.ros.batched import RecordSender
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS, apply_scheduling
from feed_twin.ros.guarded import InputGuard
from feed_twin.ros.runtime import EXIT_ERROR, EXIT_OK, FeedTwinNode, NodeOptions, node_main

STATUS_ENABLED = (
    AxisFeedback.STATUS_READY_TO_SWITCH_ON
    | AxisFeedback.STATUS_SWITCHED_ON
    | AxisFeedback.STATUS_OPERATION_ENABLED
    | AxisFeedback.STATUS_VOLTAGE_ENABLED
    | AxisFeedback.STATUS_QUICK_STOP  # set = quick stop not active
    | AxisFeedback.STATUS_REMOTE
)
STATUS_FAULT = AxisFeedback.STATUS_FAULT


DRIVE_COMMAND = FlatCodec(msg_types.DRIVE_COMMAND)
AXIS_FEEDBACK = FlatCodec(msg_types.AXIS_FEEDBACK)
AXIS_STATE = FlatCodec(msg_types.AXIS_STATE)
# The AxisFeedback numbers as `_exchange` packs them (the MEAS_* slots 0..4 are in this order).
FEEDBACK_NUMBERS = (
    "header.stamp.sec",
    "header.stamp.nanosec",
    "encoder_counts",
    "encoder_angle",
    "scale_position",
    "i_a",
    "i_b",
    "i_c",
    "i_d",
    "i_q",
    "u_dc",
    "u_d_ref",
    "u_q_ref",
    "following_error",
    "mode",
    "status_word",
    "fault_code",
)
_COMMAND_FIELDS = (
    "header.stamp.sec",
    "header.stamp.nanosec",
    "mode",
    "enable",
    "position",
    "velocity",
    "torque",
    "i_q",
    "i_d",
    "u_d",
    "u_q",
)
# The command values a setpoint may not take absurd (feed_twin.nodeset.guard), as `check_values`
# names them, and where they start in `_COMMAND_FIELDS` (position .. u_q, in this order).
_CHECKED = ("position", "velocity", "torque", "i_q", "i_d", "u_d", "u_q")
_CHECKED_FROM = _COMMAND_FIELDS.index("position")
_CHECKED_BOUNDS = bounds_of(_CHECKED)


class CommandReader:
    """DriveCommand bytes (as the controller made them, before the run's signature went on
    and after it came off) -> DriveSetpoint, fast for the axis label this node expects."""

    def __init__(self, axis_label: str) -> None:
        self.layout = DRIVE_COMMAND.fixed({"axis": axis_label})
        self._pick = operator.itemgetter(*(self.layout.index(n) for n in _COMMAND_FIELDS))

    def values(self, data: bytes) -> tuple:
        """The `_COMMAND_FIELDS` of DriveCommand bytes, in that order."""
        return self._pick(self.layout.decode(data))

    @staticmethod
    def setpoint(values: tuple) -> DriveSetpoint:
        """The DriveSetpoint of `values` (the `_COMMAND_FIELDS`)."""
        sec, nsec, mode, enable, x, v, tau, i_q, i_d, u_d, u_q = values
        return DriveSetpoint(
            t_ns=sec * NS_PER_S + nsec,
            mode=mode,
            enable=enable,
            position_m=x,
            velocity_m_s=v,
            torque_Nm=tau,
            i_q_A=i_q,
            i_d_A=i_d,
            u_d_V=u_d,
            u_q_V=u_q,
        )

    def __call__(self, data: bytes) -> DriveSetpoint:
        return self.setpoint(self.values(data))


def setpoint_from(data: bytes) -> DriveSetpoint:
    """A DriveSetpoint from DriveCommand bytes of any axis label."""
    return CommandReader("")(data)


class SimNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        host: DriveHost,
        settings: SimSettings,
        *,
        protection: DriveProtection | None = None,
        context=None,
    ) -> None:
        super().__init__(SIM_NODE, options, context=context)
        self.host = host
        self.protection = protection
        self.settings = settings
        self.end = RunEnd(round(settings.settle_s * NS_PER_S))
        self.axis_label = axis_label = settings.axis_label
        self.joint_name = settings.joint_name
        self.realtime = realtime = settings.realtime
        self.clock_divider = settings.clock_divider
        max_time_s = settings.max_time_s
        self.max_ns = None if max_time_s is None else round(max_time_s * NS_PER_S)
        self.started = False
        self.steps = 0
        self.missed_steps = 0
        self.lateness_s: list[float] = []
        self.wall_start: float | None = None
        self.wall_end: float | None = None
        self._pending: dict[int, DriveSetpoint] = {}
        # a machine's sim (its own axis clock) starts with the program, which the G-code node
        # starts once every axis is up: all axes then start together, also in real time
        self._go = settings.clock_topic == "/clock"
        self._progress_at = 0.0
        self._feedback_pub = self.create_publisher(AxisFeedback, self.topics.feedback, DATA_QOS)
        self._state_pub = self.create_publisher(AxisState, self.topics.state, DATA_QOS)
        self._joint_pub = self.create_publisher(JointState, self.topics.joint_states, DATA_QOS)
        self._clock_pub = self.create_publisher(Clock, settings.clock_topic, DATA_QOS)
        self._run_pub = self.create_publisher(String, self.topics.run_state, LATCHED_QOS)
        self._record = None
        if settings.record_batch:
            batched = self.topics.batched(SIM_NODE)
            record = self.topics.record(SIM_NODE)
            self._record = RecordSender(self, record, batched, settings.record_batch)
            self._record_feedback = self._record.index(self.topics.feedback)
            self._record_state = self._record.index(self.topics.state)
            self._record_joint = self._record.index(self.topics.joint_states)
        self.create_subscription(
            DriveCommand, self.topics.drive_command, self._on_command, DATA_QOS, raw=True
        )
        self.create_subscription(
            String, self.topics.program_state, self._on_program_state, LATCHED_QOS
        )
        # Twice the controller's timeout: when the NC stream is missing the controller stays
        # silent too, and the node nearest the cause should be the one that reports.
        self._command_dog = self.watch_input(
            self.topics.drive_command,
            msg_types.DRIVE_COMMAND,
            armed=lambda: self.started and not self.done and not self.realtime,
            timeout_s=2.0 * options.input_timeout_s,
        )
        self._joint = JointStateLayout(settings.joint_name)
        self._clock = Clock()
        self._guard = InputGuard(
            self,
            (self.topics.drive_command, self.topics.program_state),
            axis_label,
            nc_topics=(self.topics.program_state,),
        )
        self._read_command = CommandReader(axis_label)
        self._feedback_layout = AXIS_FEEDBACK.fixed({"axis": axis_label})
        self._state_layout = AXIS_STATE.fixed({"axis": axis_label})
        if self._feedback_layout.numbers != FEEDBACK_NUMBERS:
            raise ValueError(f"AxisFeedback fields {self._feedback_layout.numbers} changed")
        if self._state_layout.numbers[2:] != TRUTH_FIELDS:
            raise ValueError(f"AxisState fields {self._state_layout.numbers} != {TRUTH_FIELDS}")
        self._i_position = TRUTH_FIELDS.index("table_position")
        self._i_velocity = TRUTH_FIELDS.index("table_velocity")
        self._i_screw = TRUTH_FIELDS.index("screw_force")
        for note in apply_scheduling(
            cpu=settings.exchange_cpu,
            priority=settings.realtime_priority if realtime else 0,
            cpu_latency_us=settings.cpu_latency_us,
        ):
            self.get_logger().info(f"scheduling: {note}")
        if realtime:
            # The controller raises its own priority on this announcement (latched).
            priority = settings.realtime_priority
            self._run_pub.publish(self._run_text(realtime_announcement(priority)))
        outputs = (
            (self._feedback_pub, self._state_pub, self._joint_pub)
            if self._record is None
            else (self._record.publisher,)
        )
        self.start_heartbeat(when=lambda: self.recorder_listens(outputs))

    def poll(self) -> float | None:
        """Called by the spin loop; starts the run once every peer is up; paces real time."""
        if not self.started:
            if self.peers_alive() and self._subscribers_ready() and self._go:
                self.started = True
                self.wall_start = time.monotonic()
                self._exchange(None)
                if self.realtime:
                    # The timeline starts once the first exchange is out: its one-off costs
                    # (the first sample to each reader) are set-up, not a late exchange.
                    self.wall_start = time.monotonic()
                return 0.0  # pace from now on: come back before the first deadline
            return 0.01
        now = time.monotonic()
        if now - self._progress_at > 0.5:
            self._progress_at = now
            print(f"PROGRESS {self.host.t_ns / NS_PER_S:.3f}", file=sys.stderr, flush=True)
        if not self.realtime or self.done or self.wall_start is None:
            return None
        deadline = self.wall_start + self.host.k * self.host.exchange_ns / NS_PER_S
        now = time.monotonic()
        if now >= deadline:
            if self._end_if_passed():  # the controller sends nothing past the end: no miss
                return None
            self.lateness_s.append(now - deadline)
            t_ns = self.host.t_ns
            setpoint = self._pending.pop(t_ns, None)
            if setpoint is None:
                # Missed: a drive applies the newest setpoint it has (a late one included).
                self.missed_steps += 1
                late = [t for t in self._pending if t < t_ns]
                setpoint = self._pending[max(late)] if late else None
            self._pending = {t: s for t, s in self._pending.items() if t > t_ns}
            self._exchange(setpoint)
            return 0.0
        # Block on DDS events until the deadline: the executor's timed wait is precise to tens
        # of microseconds, and a busy poll would take the CPU the controller needs.
        return max(deadline - now, 0.0)

    def _subscribers_ready(self) -> bool:
        return self._feedback_pub.get_subscription_count() >= 1 and (
            self.count_publishers(self.topics.drive_command) >= 1
        )

    def _on_program_state(self, msg: String) -> None:
        text = self._guard.admit_text(self.topics.program_state, msg.data)
        if text is None:
            return
        parsed = parse_program_state(text)
        if parsed is None:
            self._guard.refuse(
                "program_state", self.topics.program_state, f"{text[:80]!r} (malformed)"
            )
            return
        word, stamp_ns, text = parsed
        if word == "running":
            self._go = True
        if self.end.learn(word, stamp_ns):
            if self.started:
                self._end_if_passed()  # the last exchange may have run already
        elif word == "error":
            self._end(EXIT_ERROR, f"done error: {text.partition(' ')[2]}")

    def _end_if_passed(self) -> bool:
        """End the run when the next exchange lies past the program's end (run_end.py)."""
        if not self.end.passed(self.host.t_ns):
            return False
        self._end(EXIT_OK, f"done {self.end.word} at {self.host.t_ns} ns")
        return True

    def on_run_done(self, text: str) -> None:
        """Its own announcement comes back on the latched topic; _end has already finished."""

    def _end(self, code: int, text: str) -> None:
        if self.done:
            return
        self.run_ended = True
        self.wall_end = time.monotonic()
        if self._record is not None:
            self._record.flush()  # the recorder's copies before the end they precede
        self._run_pub.publish(self._run_text(text))
        # "done error" is the run_state word for the peers; the log (and the run's reason,
        # feed_twin.ros.launch) says what went wrong only.
        self.finish(code, "" if code == EXIT_OK else text.removeprefix("done error: "))

    def _run_text(self, text: str) -> String:
        return String(data=self.auth.sign_text(self.topics.run_state, text))

    def _on_command(self, data: bytes) -> None:
        setpoint = self._admit(data)
        if setpoint is None:
            return
        self._command_dog.feed()
        if self.realtime:
            self._pending[setpoint.t_ns] = setpoint
            return
        if not self.started or self.done:
            return
        if setpoint.t_ns != self.host.t_ns:
            self._end(
                EXIT_ERROR,
                f"done error: DriveCommand stamped {setpoint.t_ns} ns, the simulation is at "
                f"{self.host.t_ns} ns (lockstep broken: two controllers on one axis?)",
            )
            return
        self._exchange(setpoint)

    def _admit(self, data: bytes) -> DriveSetpoint | None:
        """The setpoint of a DriveCommand of this run with usable values, else None (refused
        with a warning: another publisher's message, garbage, NaN)."""
        topic = self.topics.drive_command
        reader = self._read_command
        admitted = self._guard.admit(topic, data)
        if admitted is None:
            return None  # not the controller's: it does not move the axis
        data = admitted
        try:
            values = reader.values(data)
        except Exception as exc:  # noqa: BLE001 - any undecodable message is dropped, not fatal
            self._guard.refuse("malformed", topic, f"undecodable ({type(exc).__name__})")
            return None
        checked = values[_CHECKED_FROM:]
        if not within_bounds(checked, _CHECKED_BOUNDS):
            bad = check_values(dict(zip(_CHECKED, checked, strict=True)))
            if bad is not None:
                self._guard.refuse("values", topic, bad)
                return None
        return reader.setpoint(values)

    def _exchange(self, setpoint: DriveSetpoint | None) -> None:
        if self._end_if_passed():
            return
        if self.max_ns is not None and self.host.t_ns > self.max_ns:
            self._end(EXIT_OK, f"done time limit at {self.host.t_ns} ns")
            return
        host = self.host
        try:
            t_ns, row = host.advance(setpoint)
        except Exception as exc:  # noqa: BLE001 - a diverged plant ends the run with its message
            self._end(EXIT_ERROR, f"done error: {exc}")
            return
        self.steps += 1
        # The controller waits for the feedback: it goes out first, the record messages after.
        sec, nsec = divmod(t_ns, NS_PER_S)
        meas, counts, i_d, i_q, error = host.feedback(row)
        u_d_ref, u_q_ref = host.voltage_refs(row)
        fault, enabled = host.fault(row)
        truth = host.truth(row)
        trip = self._protect(t_ns, fault, error, i_q, truth[self._i_velocity])
        if trip is not None:
            # Fault reaction (CiA 402 "disable voltage"): the power stage goes off, the status
            # word shows the fault and its code, and the run ends naming the limit.
            fault, enabled = trip.code, False
            self.host.setpoint = dataclasses.replace(self.host.setpoint, enable=False)
        feedback = self._feedback_layout.encode(
            (
                sec, nsec, counts, *meas[: sig.MEAS_U_DC_V], i_d, i_q,
                meas[sig.MEAS_U_DC_V], u_d_ref, u_q_ref, error, host.setpoint.mode,
                (STATUS_ENABLED if enabled else 0) | (STATUS_FAULT if fault else 0), fault,
            )
        )  # fmt: skip
        sign = self.auth.sign
        feedback = sign(self.topics.feedback, feedback)
        self._feedback_pub.publish(feedback)
        state = sign(self.topics.state, self._state_layout.encode((sec, nsec, *truth)))
        self._state_pub.publish(state)
        record = self._record
        if record is not None:
            record.add(self._record_feedback, feedback)
            record.add(self._record_state, state)
        if trip is None:
            self._publish_slow(t_ns, truth)
        if record is not None:
            record.end_exchange()
        if trip is not None:
            self._end(EXIT_ERROR, f"done error: {trip.text()}")
            return
        if fault:
            from feed_twin.control.layout import fault_reason

            self.get_logger().error(
                f"drive fault at t = {t_ns * 1e-9:.6f} s: {fault_reason(fault)}",
                throttle_duration_sec=1.0,
            )
        self._end_if_passed()

    def _publish_slow(self, t_ns: int, truth) -> None:
        """Joint states and the clock, every clock_divider exchanges."""
        host = self.host
        if (host.k - 1) % self.clock_divider:
            return
        sec, nsec = divmod(t_ns, NS_PER_S)
        # Tools get joint states and the clock at a lower rate; every message carries its stamp.
        joint = self.auth.sign(
            self.topics.joint_states,
            self._joint.encode(
                sec, nsec, truth[self._i_position], truth[self._i_velocity], truth[self._i_screw]
            ),
        )
        # The clock reads the time the simulation has reached: the end of this exchange.
        csec, cnsec = divmod(t_ns + host.exchange_ns, NS_PER_S)
        self._clock.clock.sec, self._clock.clock.nanosec = csec, cnsec
        self._joint_pub.publish(joint)
        if self._record is not None:
            self._record.add(self._record_joint, joint)
        self._clock_pub.publish(self._clock)

    def _protect(self, t_ns: int, fault: int, error: float, i_q: float, v: float):
        """The drive's trip at this exchange (feed_twin.nodeset.protection), or None."""
        if fault in (sig.FAULT_FOLLOWING_ERROR, sig.FAULT_OVERCURRENT):
            # The drive's own loops tripped (the kernel latched it): end the run on it too.
            return Trip(t_ns=t_ns, code=fault, value=math.nan, limit=math.nan, source="drive")
        if self.protection is None:
            return None
        return self.protection.check(t_ns, error, i_q, v)

    def timing_report(self) -> dict[str, float | int | None]:
        wall = (self.wall_end or time.monotonic()) - (self.wall_start or time.monotonic())
        return pacing_report(
            steps=self.steps,
            period_s=self.host.exchange_ns / NS_PER_S,
            wall_s=wall,
            lateness_s=self.lateness_s if self.realtime else None,
            missed_steps=self.missed_steps,
        )

    def on_shutdown(self, reason: str) -> None:
        if self._record is not None:
            with contextlib.suppress(Exception):  # the context may be shutting down
                self._record.flush()
        if not self.done or self.exit_code != EXIT_OK:
            # The context may already be shutting down; the others also stop on lost heartbeats.
            with contextlib.suppress(Exception):
                self._run_pub.publish(self._run_text(f"done error: {reason or 'stopped'}"))
        print("TIMING " + json.dumps(self.timing_report()), file=sys.stderr, flush=True)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--realtime", action="store_true")
    parser.add_argument("--max-time", type=float, default=None, help="simulated seconds at most")
    parser.add_argument(
        "--axis-clock",
        action="store_true",
        help="publish the clock as <namespace>/clock: one G-code node holds a machine's axes "
        "together by their clocks (feed_twin.machine.nodes)",
    )


def build(args: argparse.Namespace, ros, options: NodeOptions, context) -> SimNode:
    from feed_twin.ros.launch import stage

    stage("sim: compiling the drive and plant kernels (numba; cached after the first run)")
    host = build_drive_host(args.config, ros)
    host.warm_up()  # before the first heartbeat: a compiling node must not look dead
    stage("sim: waiting for its peers")
    clock_topic = f"{options.topics.namespace}/clock" if args.axis_clock else "/clock"
    settings = SimSettings.of(
        ros, realtime=args.realtime, max_time_s=args.max_time, clock_topic=clock_topic
    )
    return SimNode(
        options,
        host,
        settings,
        protection=protection_for_config(args.config, ros, host.exchange_ns),
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    return node_main(argv, prog="sim node", configure=configure, build=build)


if __name__ == "__main__":
    sys.exit(main())
