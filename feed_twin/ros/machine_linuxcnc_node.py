"""LinuxCNC as the machine of a machine's shadow twin: the bridge node for every axis.

The single-axis bridge (feed_twin/ros/linuxcnc_node.py: one program on LinuxCNC, every 1 kHz
servo period, stamps and pairing of feed_twin.linuxcnc.bridge) publishing, per simulated axis
of the machine config, that joint's `/<machine>/<axis>/command` (AxisCommand) and
`/<machine>/<axis>/joint_states` (JointState, position only: the HAL servo has no effort), the
samples its twin node shadows; `<first axis>/linuxcnc/servo` (ServoSample) carries every joint.
It serves every axis's namespace (heartbeats, peers, the end of the run on each `run_state`),
starts LinuxCNC once every twin listens and the recorder records each topic, and publishes at
most WINDOW periods ahead of the slowest twin's output. The bridge latency and the latency to the
twin's output are the first axis's.
"""

from __future__ import annotations

import argparse
import functools
import struct
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from feed_twin_msgs.msg import AxisCommand, TwinResidual
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from feed_twin.linuxcnc.bridge import BridgeBatch
from feed_twin.linuxcnc.runner import LinuxcncRun
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS
from feed_twin.ros.linuxcnc_node import COMMAND, LinuxcncNode, _servo_sample, run_starter
from feed_twin.ros.linuxcnc_node import configure as bridge_configure
from feed_twin.ros.runtime import PEER_TIMEOUT_S, NodeOptions, start_node
from feed_twin.shadow.bagstreams import encode_joint_state
from feed_twin.shadow.replay import twin_namespace

NS_PER_S = 1_000_000_000
_STAMP = struct.Struct("<iI")  # header.stamp right after the 4-byte CDR encapsulation


class MachineLinuxcncNode(LinuxcncNode):
    def __init__(
        self,
        options: NodeOptions,
        *,
        start_run: Callable[[], LinuxcncRun],
        joints: dict[str, int],
        period_s: float,
        context=None,
    ) -> None:
        """`joints`: NC axis -> LinuxCNC joint of every shadowed axis; the first is the node's
        own (options.axis), the others are options.other_axes."""
        first = options.axis.upper()
        super().__init__(
            options, start_run=start_run, joint=joints[first], period_s=period_s, context=context
        )
        # per axis: (joint, command encoder, command publisher, joint_states publisher)
        self._axes = {first: (joints[first], self._command, self._cmd_pub, self._js_pub)}
        self._twin_stamps = dict.fromkeys(joints, -1)  # latest twin output per axis [ns]
        for axis, joint in joints.items():
            if axis == first:
                continue
            topics = AxisTopics(machine=options.machine, axis=axis.lower())
            self._axes[axis] = (
                joint,
                COMMAND.fixed({"header.frame_id": "", "axis": axis}),
                self.create_publisher(AxisCommand, topics.command, DATA_QOS),
                self.create_publisher(JointState, topics.joint_states, DATA_QOS),
            )
            self._run_pubs.append(self.create_publisher(String, topics.run_state, LATCHED_QOS))
            self.create_subscription(
                TwinResidual,
                node_role("twin").topic(twin_namespace(topics.command), "residual"),
                functools.partial(self._on_axis_output, axis),
                DATA_QOS,
                raw=True,
            )
        self._first = first

    def _ready(self) -> bool:
        publishers = [p for *_, cmd, js in self._axes.values() for p in (cmd, js)]
        return (
            self.peers_alive()
            and all(js.get_subscription_count() > 0 for *_, js in self._axes.values())
            and self.recorder_listens([*publishers, self._servo_pub])
        )

    def _on_twin_output(self, data: bytes) -> None:
        self._on_axis_output(self._first, data)

    def _on_axis_output(self, axis: str, data: bytes) -> None:
        sec, nsec = _STAMP.unpack_from(data, 4)
        stamp = sec * NS_PER_S + nsec
        self._twin_stamps[axis] = max(self._twin_stamps[axis], stamp)
        # the window follows the slowest twin: none is flooded
        self._twin_ns = min(self._twin_stamps.values())
        if axis == self._first and self.bridge is not None:
            self.bridge.twin_output(stamp, now_s=time.monotonic())

    def _publish(self, b: BridgeBatch, start: int, stop: int) -> None:
        period_ns = round(self.period_s * NS_PER_S)
        for i in range(start, stop):
            stamp = int(b.stamp_ns[i])
            sec, nsec = divmod(stamp, NS_PER_S)
            line = int(b.line[i])
            for axis, (j, command, cmd_pub, js_pub) in self._axes.items():
                values = (sec, nsec, float(b.pos_cmd_m[i, j]), float(b.vel_cmd_m_s[i, j]),
                          float(b.acc_cmd_m_s2[i, j]), line)  # fmt: skip
                sign = self.auth.sign  # the run's signature (feed_twin.nodeset.auth)
                cmd_pub.publish(sign(cmd_pub.topic_name, command.encode(values)))
                if stamp > 0:  # row k's feedback is period k - 1's (feed_twin.linuxcnc.bridge)
                    fb = float(b.pos_fb_m[i, j])
                    js = encode_joint_state(stamp - period_ns, [axis.lower()], [fb], [], [])
                    js_pub.publish(sign(js_pub.topic_name, js))
            servo = serialize_message(_servo_sample(b, i, sec, nsec, self._first))
            self._servo_pub.publish(self.auth.sign(self._servo_pub.topic_name, servo))


def configure(parser: argparse.ArgumentParser) -> None:
    bridge_configure(parser)  # --config: the first shadowed axis's file (its ros: section)
    parser.add_argument("--machine-config", required=True, type=Path, help="machine YAML")
    parser.add_argument("--axes", required=True, help="the shadowed NC axes, e.g. X,Y,Z")
    parser.add_argument("--peer-timeout", type=float, default=PEER_TIMEOUT_S, help="[s]")


def build(args: argparse.Namespace, context) -> MachineLinuxcncNode:
    from feed_twin.linuxcnc.machine_shadow import linuxcnc_machine, machine_joints
    from feed_twin.machine.config import load_machine_config
    from feed_twin.nodeset.config import load_node_set_config

    ros = load_node_set_config(args.config)
    machine = load_machine_config(args.machine_config).select(args.axes.split(","))
    nc, servo = linuxcnc_machine(machine)
    joints = machine_joints(machine)
    return MachineLinuxcncNode(
        NodeOptions(
            machine=ros.machine,
            axis=ros.axis,
            peers=tuple(p for p in args.peers.split(",") if p),
            startup_timeout_s=args.startup_timeout,
            input_timeout_s=args.input_timeout,
            peer_timeout_s=args.peer_timeout,
            other_axes=tuple(a.lower() for a in joints if a.lower() != ros.axis),
        ),
        start_run=run_starter(args, nc, servo),
        joints=joints,
        period_s=servo.servo_period_s,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="machine linuxcnc node", description=__doc__.splitlines()[0] if __doc__ else None
    )
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("machine linuxcnc node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
