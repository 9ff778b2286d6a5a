"""LinuxCNC as the machine of a machine's shadow twin: the bridge node for every axis.

The single-axis bridge (feed_twin/ros/linuxcnc_node.py: one program on LinuxCNC, every 1 kHz
servo period, stamps and pairing of feed_twin.linuxcnc.bridge) sending, per simulated axis
of the machine config, that joint's `/<machine>/<axis>/command` (AxisCommand) and
`/<machine>/<axis>/joint_states` (JointState, position only: the HAL servo has no effort), the
samples its twin node shadows, packed on `/<machine>/<axis>/linuxcnc/batch`;
`<first axis>/linuxcnc/servo` (ServoSample, in the first axis's batch) carries every joint.
It serves every axis's namespace (heartbeats, peers, the end of the run on each `run_state`),
starts LinuxCNC once every twin listens and the recorder records each topic, and publishes at
most WINDOW periods ahead of the slowest twin's output. The bridge latency and the latency to the
twin's output are the first axis's.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from std_msgs.msg import String

from feed_twin.linuxcnc.runner import LinuxcncRun
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.ros.dds import LATCHED_QOS, apply_nice
from feed_twin.ros.linuxcnc_node import LinuxcncNode, run_starter
from feed_twin.ros.linuxcnc_node import configure as bridge_configure
from feed_twin.ros.runtime import PEER_TIMEOUT_S, NodeOptions, start_node


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
        for axis, joint in joints.items():
            if axis == first:
                continue
            topics = AxisTopics(machine=options.machine, axis=axis.lower())
            self.add_axis(axis, joint, topics)
            self._run_pubs.append(self.create_publisher(String, topics.run_state, LATCHED_QOS))


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
    node = MachineLinuxcncNode(
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
    apply_nice(node, args.nice)  # ros.linuxcnc_nice (the plan's); LinuxCNC inherits it
    return node


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="machine linuxcnc node", description=__doc__.splitlines()[0] if __doc__ else None
    )
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("machine linuxcnc node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
