"""The controller node: NC setpoints + drive feedback -> DriveCommand, once per exchange.

Subscribes `command` (AxisCommand, from the G-code node or a real NC) and `feedback` (AxisFeedback,
from the sim node or a real drive); for every feedback sample at time t it waits until the NC
setpoint for t is known (a setpoint stamped >= t has arrived, or the program has finished, after
which the last setpoint is held at standstill), runs `controller_core.ControllerCore` and publishes
`drive_command` stamped t, up to the run's end (`settle_s` after the program's finish,
feed_twin.nodeset.run_end): past it, feedback gets no answer. All control maths is in
feed_twin.control; this file only converts messages. With `ros.record_batch` N > 0 the recorder's
copies of the DriveCommands go to it packed, one RecordBatch per N exchanges
(feed_twin.ros.batched). With `--command-batch` (a machine's node set) the NC setpoints come packed
from the G-code node on `command_batch` (several AxisCommands to a RecordBatch,
feed_twin/ros/gcode_node.py) instead of on `command`: each is checked and used as if it had come
alone.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import operator
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, DriveCommand
from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from std_msgs.msg import String

from feed_twin.control.config import ControllerConfig, load_controller_config
from feed_twin.core import signals as sig
from feed_twin.core.config import ConfigError, load_yaml
from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.config import NodeLoopGains
from feed_twin.nodeset.controller_core import ControllerCore
from feed_twin.nodeset.guard import bounds_of, check_values, parse_program_state, within_bounds
from feed_twin.nodeset.nc_buffer import NcBuffer
from feed_twin.nodeset.node_settings import ControllerSettings
from feed_twin.nodeset.pacing import announced_priority
from feed_twin.nodeset.record_batch import messages_of
from feed_twin.nodeset.run_end import RunEnd
from feed_twin.nodeset.topics import CONTROLLER_NODE
from feed_twin.nodeset.wire import NS_PER_S, DriveSetpoint, NcSample
from feed_twin.ros.batched import RecordSender
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS, apply_scheduling
from feed_twin.ros.guarded import InputGuard
from feed_twin.ros.runtime import EXIT_ERROR, FeedTwinNode, NodeOptions, node_main

AXIS_COMMAND = FlatCodec(msg_types.AXIS_COMMAND)
AXIS_FEEDBACK = FlatCodec(msg_types.AXIS_FEEDBACK)
DRIVE_COMMAND = FlatCodec(msg_types.DRIVE_COMMAND)


class MessageIO:
    """The controller node's message conversions, fast for its axis label (any label decodes)."""

    def __init__(self, axis_label: str) -> None:
        # messages as the nodes make them: an empty frame_id, which the run's signature fills
        # on the wire (feed_twin.nodeset.auth; the node signs and admits)
        self.command = AXIS_COMMAND.fixed({"axis": axis_label})
        self.feedback = AXIS_FEEDBACK.fixed({"axis": axis_label})
        self.drive = DRIVE_COMMAND.fixed({"axis": axis_label})
        self._nc = operator.itemgetter(*(self.command.index(n) for n in _NC_FIELDS))
        self._fb = operator.itemgetter(
            *(
                self.feedback.index(n)
                for n in ("header.stamp.sec", "header.stamp.nanosec", *_MEAS_FIELDS)
            )
        )
        expected = (
            "header.stamp.sec", "header.stamp.nanosec", "mode", "enable", "position",
            "velocity", "torque", "i_q", "i_d", "u_d", "u_q", "effort",
        )  # fmt: skip
        if self.drive.numbers != expected:
            raise ValueError(f"DriveCommand fields {self.drive.numbers} != {expected}")

    def nc_values(self, data: bytes) -> tuple:
        """The `_NC_FIELDS` of AxisCommand bytes, in that order."""
        return self._nc(self.command.decode(data))

    @staticmethod
    def nc_sample_of(values: tuple) -> NcSample:
        """The NcSample of `values` (the `_NC_FIELDS`)."""
        sec, nsec, x, v, a, line = values
        return NcSample(
            t_ns=sec * NS_PER_S + nsec,
            position_m=x,
            velocity_m_s=v,
            acceleration_m_s2=a,
            line=line,
        )

    def feedback_sample(self, data: bytes, out: np.ndarray) -> int:
        """Fill the MEAS_* vector from AxisFeedback bytes; returns the stamp [ns]."""
        values = self._fb(self.feedback.decode(data))
        out[:] = values[2:]
        return values[0] * NS_PER_S + values[1]

    def drive_command(self, sp: DriveSetpoint) -> bytes:
        sec, nsec = divmod(sp.t_ns, NS_PER_S)
        return self.drive.encode(
            (
                sec, nsec, sp.mode, sp.enable, sp.position_m, sp.velocity_m_s, sp.torque_Nm,
                sp.i_q_A, sp.i_d_A, sp.u_d_V, sp.u_q_V, 0.0,
            )
        )  # fmt: skip


# The AxisCommand numbers a controller reads, and those that may not be absurd (as
# `check_values` names them; the position, velocity and acceleration, in this order).
_NC_FIELDS = (
    "header.stamp.sec", "header.stamp.nanosec", "position", "velocity", "acceleration", "line",
)  # fmt: skip
_NC_CHECKED = ("position", "velocity", "acceleration")
_NC_CHECKED_BOUNDS = bounds_of(_NC_CHECKED)
# AxisFeedback fields of the MEAS_* slots, in slot order.
_MEAS_FIELDS = ("encoder_angle", "scale_position", "i_a", "i_b", "i_c", "u_dc")
assert len(_MEAS_FIELDS) == sig.MEAS_SIZE


class ControllerNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        config: ControllerConfig,
        settings: ControllerSettings,
        *,
        gains: NodeLoopGains | None = None,
        context=None,
    ) -> None:
        super().__init__(CONTROLLER_NODE, options, context=context)
        exchange_period_s = settings.exchange_period_s
        self.core = ControllerCore(
            config, boundary=settings.boundary, exchange_period_s=exchange_period_s, gains=gains
        )
        axis_label, command_batch = settings.axis_label, settings.command_batch
        for note in self.core.notes:
            self.get_logger().info(note)
        self.core.warm_up()
        self.axis_label = axis_label
        self.exchange_ns = round(exchange_period_s * NS_PER_S)
        # where the NC setpoints come from: one AxisCommand each, or packed (--command-batch)
        command_topic = self.topics.command_batch if command_batch else self.topics.command
        self._guard = InputGuard(
            self,
            (command_topic, self.topics.program_state, self.topics.feedback),
            axis_label,
            nc_topics=(self.topics.command, self.topics.program_state),
        )
        self.io = MessageIO(axis_label)
        self.nc = NcBuffer()
        self.end = RunEnd(round(settings.settle_s * NS_PER_S))
        self._pending: collections.deque[bytes] = collections.deque()
        self._paused = False
        self._meas = np.zeros(sig.MEAS_SIZE)
        self.steps = 0
        self._pub = self.create_publisher(DriveCommand, self.topics.drive_command, DATA_QOS)
        self._record = None
        if settings.record_batch:
            self._record = RecordSender(
                self,
                self.topics.record(CONTROLLER_NODE),
                self.topics.batched(CONTROLLER_NODE),
                settings.record_batch,
            )
        if command_batch:
            self.create_subscription(
                RecordBatchMsg, command_topic, self._on_command_batch, DATA_QOS, raw=True
            )
        else:
            self.create_subscription(
                AxisCommand, command_topic, self._on_command, DATA_QOS, raw=True
            )
        self.create_subscription(
            AxisFeedback, self.topics.feedback, self._on_feedback, DATA_QOS, raw=True
        )
        self.create_subscription(
            String, self.topics.program_state, self._on_program_state, LATCHED_QOS
        )
        # A command stream is due once drive feedback flows; silence while paused is expected.
        self._command_dog = self.watch_input(
            command_topic,
            msg_types.RECORD_BATCH if command_batch else msg_types.AXIS_COMMAND,
            armed=lambda: bool(self._pending) and not self._paused and not self.nc.finished,
        )
        self._feedback_dog = self.watch_input(
            self.topics.feedback,
            msg_types.AXIS_FEEDBACK,
            armed=lambda: self.peers_alive() and self.nc.latest_ns is not None and not self.steps,
        )
        for note in apply_scheduling(cpu=settings.exchange_cpu):
            self.get_logger().info(f"scheduling: {note}")
        outputs = (self._pub,) if self._record is None else (self._record.publisher,)
        self.start_heartbeat(when=lambda: self.recorder_listens(outputs))

    def on_run_state(self, text: str) -> None:
        priority = announced_priority(text)
        if priority is not None and priority > 0:
            for note in apply_scheduling(priority=priority):
                self.get_logger().info(f"scheduling: {note}")

    def _on_command(self, data: bytes) -> None:
        if self._take_command(data, self.topics.command):
            self._serve()

    def _on_command_batch(self, data: bytes) -> None:
        topic = self.topics.command_batch
        try:
            messages = messages_of(data, self.topics.command)
        except ValueError as exc:
            self._guard.refuse("malformed", topic, f"a RecordBatch refused: {exc}")
            return
        if any([self._take_command(m, topic) for m in messages]):
            self._serve()

    def _take_command(self, data: bytes, topic: str) -> bool:
        """Check one AxisCommand and add its setpoint; False: refused."""
        admitted = self._guard.admit(self.topics.command, data)
        if admitted is None:
            return False
        data = admitted
        try:
            values = self.io.nc_values(data)
        except Exception as exc:  # noqa: BLE001 - any undecodable message is dropped, not fatal
            self._guard.refuse("malformed", topic, f"undecodable ({type(exc).__name__})")
            return False
        checked = values[2:5]
        if not within_bounds(checked, _NC_CHECKED_BOUNDS):
            bad = check_values(dict(zip(_NC_CHECKED, checked, strict=True)))
            if bad is not None:
                self._guard.refuse("values", topic, bad)
                return False
        sample = self.io.nc_sample_of(values)
        self.nc.add(sample)
        self._command_dog.feed()
        return True

    def _on_feedback(self, data: bytes) -> None:
        admitted = self._guard.admit(self.topics.feedback, data)
        if admitted is None:
            return  # not the sim's: it neither moves the axis nor ends the run
        self._pending.append(admitted)
        self._feedback_dog.feed()
        self._serve()

    def _on_program_state(self, msg: String) -> None:
        text = self._guard.admit_text(self.topics.program_state, msg.data)
        if text is None:
            return
        parsed = parse_program_state(text)
        if parsed is None:
            self._guard.refuse(
                "program_state", self.topics.program_state,
                f"{text[:80]!r} (malformed)",
            )  # fmt: skip
            return
        state, stamp_ns, _ = parsed
        self._paused = state == "paused"
        self.end.learn(state, stamp_ns)
        if state in ("finished", "stopped"):
            self.nc.finish()
            self._serve()

    def _serve(self) -> None:
        while self._pending:
            # Feedback latched at t_k sets the setpoint the drive applies from t_k+1 (drive_host).
            t_ns = self.io.feedback_sample(self._pending[0], self._meas) + self.exchange_ns
            if self.end.passed(t_ns):
                self._pending.clear()  # the sim ends at the same exchange (run_end.py)
                return
            nc = self.nc.for_time(t_ns)
            if nc is None:
                return
            self._pending.popleft()
            try:
                setpoint = self.core.step(t_ns, nc, self._meas)
            except ValueError as exc:
                self.finish(EXIT_ERROR, f"controller: at t = {t_ns * 1e-9:.6f} s: {exc}")
                return
            data = self.auth.sign(self.topics.drive_command, self.io.drive_command(setpoint))
            self._pub.publish(data)
            if self._record is not None:
                self._record.add(0, data)  # DriveCommand, its only topic
                self._record.end_exchange()
            self.steps += 1

    def on_shutdown(self, reason: str) -> None:
        if self._record is not None:
            with contextlib.suppress(Exception):  # the context may be shutting down
                self._record.flush()


def load_node_controller_config(path: Path) -> ControllerConfig:
    data = load_yaml(path)
    if "controller" not in data:
        raise ConfigError(f"{path}: no controller section")
    return load_controller_config(data["controller"], source=str(path))


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--command-batch",
        action="store_true",
        help="take the NC setpoints packed from <namespace>/command_batch (a machine's G-code "
        "node, gcode_node --command-batch) instead of from <namespace>/command",
    )


def build(args: argparse.Namespace, ros, options: NodeOptions, context) -> ControllerNode:
    return ControllerNode(
        options,
        load_node_controller_config(args.config),
        ControllerSettings.of(ros, command_batch=args.command_batch),
        gains=ros.node_gains,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    return node_main(argv, prog="controller node", configure=configure, build=build)


if __name__ == "__main__":
    sys.exit(main())
