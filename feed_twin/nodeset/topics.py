"""Names of the node set's topics, services and nodes, and the message type of each topic.

Every axis lives under its own namespace `/<machine>/<axis>/`, so several axes and machines run
side by side on one ROS graph. `/clock` is global, as ROS tools expect it. Plain Python (no ROS
imports): the runner and the recorder's type table use it too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from feed_twin.io import msg_types

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")

# Node names (one per role; the namespace tells axes apart).
GCODE_NODE = "gcode"
CONTROLLER_NODE = "controller"
SIM_NODE = "sim"
RECORDER_NODE = "recorder"
NODE_ROLES = (GCODE_NODE, CONTROLLER_NODE, SIM_NODE, RECORDER_NODE)


@dataclass(frozen=True, kw_only=True)
class Topic:
    """A topic: its name and the installed message type it carries (pkg/msg/Type)."""

    name: str
    type_name: str


@dataclass(frozen=True, kw_only=True)
class AxisTopics:
    """Topic names of one axis, and the installed message type of each."""

    machine: str
    axis: str

    def __post_init__(self) -> None:
        for field_name in ("machine", "axis"):
            value = getattr(self, field_name)
            if not isinstance(value, str) or not _NAME.match(value):
                raise ValueError(
                    f"{field_name} = {value!r}: must be a lower-case ROS name "
                    "(letters, digits, underscores; starting with a letter)"
                )

    @property
    def namespace(self) -> str:
        return f"/{self.machine}/{self.axis}"

    @property
    def command(self) -> str:  # gcode -> controller: NC setpoints
        return f"{self.namespace}/command"

    @property
    def command_batch(self) -> str:
        """gcode -> controller: the NC setpoints of `command` packed, several to a RecordBatch
        (a machine's node set, feed_twin/ros/gcode_node.py); not recorded: the bag holds them
        on `command`, so it is left out of `published`."""
        return f"{self.namespace}/command_batch"

    @property
    def drive_command(self) -> str:  # controller -> sim: CiA 402 setpoints
        return f"{self.namespace}/drive_command"

    @property
    def feedback(self) -> str:  # sim -> controller: what a drive reports
        return f"{self.namespace}/feedback"

    @property
    def state(self) -> str:  # sim -> anyone: the simulated truth
        return f"{self.namespace}/state"

    @property
    def joint_states(self) -> str:  # sim -> standard tools
        return f"{self.namespace}/joint_states"

    @property
    def program_state(self) -> str:  # gcode -> anyone: loaded/running/paused/finished/error
        return f"{self.namespace}/program_state"

    @property
    def run_state(self) -> str:  # sim -> anyone: the run's end, with its reason
        return f"{self.namespace}/run_state"

    @property
    def health(self) -> str:  # controller, sim -> operator: refused commands, foreign publishers
        return f"{self.namespace}/health"

    @property
    def heartbeat(self) -> str:  # every node -> every node: liveness
        return f"{self.namespace}/heartbeat"

    @property
    def servo(self) -> str:  # LinuxCNC bridge -> recorder: every joint of a servo period
        return f"{self.namespace}/linuxcnc/servo"

    @property
    def bridge_batch(self) -> str:
        """LinuxCNC bridge -> twin and recorder: the servo periods' `command`, `joint_states`
        (and on the first axis `servo`) packed in RecordBatches (feed_twin/ros/linuxcnc_node.py);
        the recorder writes each message under its own topic."""
        return f"{self.namespace}/linuxcnc/batch"

    clock = "/clock"

    def record(self, role: str) -> str:  # node -> recorder: its messages packed (record_batch)
        return f"{self.namespace}/record/{role}"

    def batched(self, role: str) -> tuple[str, ...]:
        """The topics node `role` sends the recorder packed when ros.record_batch > 0 (those
        only the recorder reads, and those it reads besides one other node):
        feed_twin.nodeset.record_batch."""
        return {
            SIM_NODE: (self.feedback, self.state, self.joint_states),
            CONTROLLER_NODE: (self.drive_command,),
        }.get(role, ())

    def published(self) -> tuple[Topic, ...]:
        """Every topic the node set publishes, with its message type."""
        return (
            Topic(name=self.command, type_name=msg_types.AXIS_COMMAND),
            Topic(name=self.drive_command, type_name=msg_types.DRIVE_COMMAND),
            Topic(name=self.feedback, type_name=msg_types.AXIS_FEEDBACK),
            Topic(name=self.state, type_name=msg_types.AXIS_STATE),
            Topic(name=self.joint_states, type_name=msg_types.JOINT_STATE),
            Topic(name=self.program_state, type_name=msg_types.STRING),
            Topic(name=self.run_state, type_name=msg_types.STRING),
            Topic(name=self.heartbeat, type_name=msg_types.STRING),
            Topic(name=self.health, type_name=msg_types.HEALTH_STATUS),
            Topic(name=self.clock, type_name=msg_types.CLOCK),
        )

    def types(self) -> dict[str, str]:
        """Topic name -> message type (pkg/msg/Type) of every topic the node set publishes."""
        return {topic.name: topic.type_name for topic in self.published()}

    def service(self, node: str, name: str) -> str:
        return f"{self.namespace}/{node}/{name}"
