"""The controller node: NC setpoints + drive feedback -> DriveCommand, once per exchange.

Subscribes `command` (AxisCommand, from the G-code node or a real NC) and `feedback`
(AxisFeedback, from the sim node or a real drive); for every feedback sample at time t it waits
until the NC setpoint for t is known (a setpoint stamped >= t has arrived, or the program has
finished, after which the last setpoint is held at standstill), runs `split.ControllerCore` and
publishes `drive_command` stamped t. All control maths is in feed_twin.control; this file only
converts messages.
"""

from __future__ import annotations

import argparse
import collections
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import AxisCommand, AxisFeedback, DriveCommand
from std_msgs.msg import String

from feed_twin.control import signals as sig
from feed_twin.control.config import ControllerConfig, load_controller_config
from feed_twin.io.cdr import FlatCodec
from feed_twin.io.config import ConfigError, load_yaml
from feed_twin.nodeset.split import (
    NS_PER_S,
    Boundary,
    ControllerCore,
    DriveSetpoint,
    NcBuffer,
    NcSample,
    NodeLoopGains,
)
from feed_twin.nodeset.topics import CONTROLLER_NODE
from feed_twin.ros.runtime import (
    DATA_QOS,
    EXIT_ERROR,
    LATCHED_QOS,
    FeedTwinNode,
    NodeOptions,
    node_main,
)

AXIS_COMMAND = FlatCodec("feed_twin_msgs/msg/AxisCommand")
AXIS_FEEDBACK = FlatCodec("feed_twin_msgs/msg/AxisFeedback")
DRIVE_COMMAND = FlatCodec("feed_twin_msgs/msg/DriveCommand")


def nc_sample(data: bytes) -> NcSample:
    m = AXIS_COMMAND.decode_map(data)
    return NcSample(
        t_ns=m["header.stamp.sec"] * NS_PER_S + m["header.stamp.nanosec"],
        position_m=m["position"],
        velocity_m_s=m["velocity"],
        acceleration_m_s2=m["acceleration"],
        line=m["line"],
    )


def feedback_sample(data: bytes, out: np.ndarray) -> int:
    """Fill the MEAS_* vector from AxisFeedback bytes; returns the stamp [ns]."""
    m = AXIS_FEEDBACK.decode_map(data)
    out[sig.MEAS_THETA_ENC_RAD] = m["encoder_angle"]
    out[sig.MEAS_X_SCALE_M] = m["scale_position"]
    out[sig.MEAS_I_A] = m["i_a"]
    out[sig.MEAS_I_B] = m["i_b"]
    out[sig.MEAS_I_C] = m["i_c"]
    out[sig.MEAS_U_DC_V] = m["u_dc"]
    return m["header.stamp.sec"] * NS_PER_S + m["header.stamp.nanosec"]


def drive_command(setpoint: DriveSetpoint, axis: str) -> bytes:
    sec, nsec = divmod(setpoint.t_ns, NS_PER_S)
    return DRIVE_COMMAND.encode_map(
        {
            "header.stamp.sec": sec,
            "header.stamp.nanosec": nsec,
            "axis": axis,
            "mode": setpoint.mode,
            "enable": setpoint.enable,
            "position": setpoint.position_m,
            "velocity": setpoint.velocity_m_s,
            "torque": setpoint.torque_Nm,
            "i_q": setpoint.i_q_A,
            "i_d": setpoint.i_d_A,
        }
    )


class ControllerNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        config: ControllerConfig,
        *,
        boundary: Boundary,
        exchange_period_s: float,
        axis_label: str,
        gains: NodeLoopGains | None = None,
        context=None,
    ) -> None:
        super().__init__(CONTROLLER_NODE, options, context=context)
        self.core = ControllerCore(
            config, boundary=boundary, exchange_period_s=exchange_period_s, gains=gains
        )
        for note in self.core.notes:
            self.get_logger().info(note)
        self.core.warm_up()
        self.axis_label = axis_label
        self.exchange_ns = round(exchange_period_s * NS_PER_S)
        self.nc = NcBuffer()
        self._pending: collections.deque[bytes] = collections.deque()
        self._paused = False
        self._meas = np.zeros(sig.MEAS_SIZE)
        self.steps = 0
        self._pub = self.create_publisher(DriveCommand, self.topics.drive_command, DATA_QOS)
        self.create_subscription(
            AxisCommand, self.topics.command, self._on_command, DATA_QOS, raw=True
        )
        self.create_subscription(
            AxisFeedback, self.topics.feedback, self._on_feedback, DATA_QOS, raw=True
        )
        self.create_subscription(
            String, self.topics.program_state, self._on_program_state, LATCHED_QOS
        )
        # A command stream is due once drive feedback flows; silence while paused is expected.
        self._command_dog = self.watch_input(
            self.topics.command,
            "feed_twin_msgs/msg/AxisCommand",
            armed=lambda: bool(self._pending) and not self._paused and not self.nc.finished,
        )
        self._feedback_dog = self.watch_input(
            self.topics.feedback,
            "feed_twin_msgs/msg/AxisFeedback",
            armed=lambda: self.peers_alive() and self.nc.latest_ns is not None and not self.steps,
        )
        self.start_heartbeat()

    def _on_command(self, data: bytes) -> None:
        self.nc.add(nc_sample(data))
        self._command_dog.feed()
        self._serve()

    def _on_feedback(self, data: bytes) -> None:
        self._pending.append(data)
        self._feedback_dog.feed()
        self._serve()

    def _on_program_state(self, msg: String) -> None:
        state = msg.data.split(" ", 1)[0]
        self._paused = state == "paused"
        if state in ("finished", "stopped"):
            self.nc.finish()
            self._serve()

    def _serve(self) -> None:
        while self._pending:
            # Feedback latched at t_k sets the setpoint the drive applies from t_k+1 (drive_host).
            t_ns = feedback_sample(self._pending[0], self._meas) + self.exchange_ns
            nc = self.nc.for_time(t_ns)
            if nc is None:
                return
            self._pending.popleft()
            try:
                setpoint = self.core.step(t_ns, nc, self._meas)
            except ValueError as exc:
                self.finish(EXIT_ERROR, f"controller: at t = {t_ns * 1e-9:.6f} s: {exc}")
                return
            self._pub.publish(drive_command(setpoint, self.axis_label))
            self.steps += 1


def load_node_controller_config(path: Path) -> ControllerConfig:
    data = load_yaml(path)
    if "controller" not in data:
        raise ConfigError(f"{path}: no controller section")
    return load_controller_config(data["controller"], source=str(path))


def configure(parser: argparse.ArgumentParser) -> None:
    """The controller node has no options of its own."""


def build(args: argparse.Namespace, ros, options: NodeOptions, context) -> ControllerNode:
    return ControllerNode(
        options,
        load_node_controller_config(args.config),
        boundary=ros.boundary,
        exchange_period_s=ros.exchange_period_s,
        axis_label=ros.axis.upper(),
        gains=ros.node_gains,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    return node_main(argv, prog="controller node", configure=configure, build=build)


if __name__ == "__main__":
    sys.exit(main())
