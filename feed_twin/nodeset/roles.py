"""The node roles of a run in one registry, as `feed_twin.cli.SUBCOMMANDS` is for subcommands.

A role is a kind of ROS node (the G-code NC, the controller, the simulated drive and axis, the
recorder, the shadow twin, the stand-in machine, the LinuxCNC bridges). Its entry says which
module implements it (run as `python -m <module>`, or built by `configure`/`build` in a shared
process: feed_twin/ros/host.py), whether a process may host it beside others and more than once,
whether it guards its command inputs (feed_twin/ros/guarded.py), the topics it publishes and
subscribes that other roles and the recorder rely on (name relative to its namespace, message
type from feed_twin.io.msg_types) and the launch arguments a runner passes it. The host, the
guard, the recorder and the launchers read this table; a new node is its module plus one entry
here (tests/test_roles.py iterates it).

Plain Python, no rclpy: the node modules are named, not imported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from feed_twin.io import msg_types

Direction = Literal["publishes", "subscribes"]
# the arguments every node of a run takes (feed_twin/ros/runtime.py node_parser)
COMMON_ARGUMENTS = ("--config", "--peers", "--startup-timeout", "--input-timeout")
# a machine's nodes wait longer for a silent peer (feed_twin.machine.nodes.PEER_TIMEOUT_S)
PEER_TIMEOUT = "--peer-timeout"
# the arguments of a node that serves further axes of a machine (its G-code node, recorder)
MACHINE_ARGUMENTS = (PEER_TIMEOUT, "--machine-axes", "--command-axes")
# the process that hosts several hostable nodes, and the separator of their command lines
HOST_MODULE = "feed_twin.ros.host"
HOST_SEPARATOR = "--and"


@dataclass(frozen=True, kw_only=True)
class RoleTopic:
    """One topic of a role: its name under the role's namespace, message type and direction."""

    name: str  # relative to the namespace: "residual" is `<namespace>/residual`
    type_name: str  # installed message type, pkg/msg/Type (feed_twin.io.msg_types)
    direction: Direction

    def __post_init__(self) -> None:
        if not self.name or self.name.startswith("/"):
            raise ValueError(f"name = {self.name!r}: must be relative to the namespace")
        if self.direction not in ("publishes", "subscribes"):
            raise ValueError(f"direction = {self.direction!r}: must be publishes or subscribes")


@dataclass(frozen=True, kw_only=True)
class Role:
    """One node role: what implements it, where it may run, what it sends and receives."""

    name: str  # the role's name on a host command line and in a launch plan
    node_name: str  # the ROS node's name (a namespace tells axes apart)
    module: str  # the node module: `main(argv)`, `configure(parser)`, `build(...)`
    hostable: bool  # built in a shared process by feed_twin/ros/host.py
    repeatable: bool  # a process may host it several times, each for another axis
    guarded: bool  # refuses unsigned commands and names foreign publishers (ros/guarded.py)
    own_node: bool  # a node of the run to the guard: its messages are not foreign
    machine_wide: bool = False  # one node serves every axis of a machine (from its namespace)
    topics: tuple[RoleTopic, ...] = ()
    arguments: tuple[str, ...] = ()  # launch arguments a runner may pass it, besides common

    def topic(self, namespace: str, name: str) -> str:
        """The full name of this role's topic `name` under `namespace`; KeyError if it has none."""
        if not any(t.name == name for t in self.topics):
            known = ", ".join(t.name for t in self.topics) or "none"
            raise KeyError(f"role {self.name!r} has no topic {name!r} (its topics: {known})")
        return f"{namespace.rstrip('/')}/{name}"

    def topic_types(self, namespace: str, direction: Direction = "publishes") -> dict[str, str]:
        """Full topic name -> message type of the topics this role `direction` under
        `namespace`, in the order of its entry."""
        ns = namespace.rstrip("/")
        return {f"{ns}/{t.name}": t.type_name for t in self.topics if t.direction == direction}


def _out(name: str, type_name: str) -> RoleTopic:
    return RoleTopic(name=name, type_name=type_name, direction="publishes")


def _in(name: str, type_name: str) -> RoleTopic:
    return RoleTopic(name=name, type_name=type_name, direction="subscribes")


_LIVENESS = (_out("heartbeat", msg_types.STRING), _in("heartbeat", msg_types.STRING))

ROLES: dict[str, Role] = {
    role.name: role
    for role in (
        Role(
            name="recorder",
            node_name="recorder",
            module="feed_twin.ros.recorder_node",
            hostable=True,
            repeatable=False,
            guarded=False,
            own_node=True,
            topics=_LIVENESS,
            arguments=("--bag", "--live-url", "--twin-namespace", *MACHINE_ARGUMENTS),
        ),
        Role(
            name="controller",
            node_name="controller",
            module="feed_twin.ros.controller_node",
            hostable=True,
            repeatable=True,  # a machine's controller process holds every axis's controller
            guarded=True,
            own_node=True,
            topics=(
                _in("command", msg_types.AXIS_COMMAND),
                _in("command_batch", msg_types.RECORD_BATCH),
                _in("feedback", msg_types.AXIS_FEEDBACK),
                _in("program_state", msg_types.STRING),
                _out("drive_command", msg_types.DRIVE_COMMAND),
                _out("health", msg_types.HEALTH_STATUS),
                *_LIVENESS,
            ),
            arguments=("--command-batch", PEER_TIMEOUT),
        ),
        Role(
            name="sim",
            node_name="sim",
            module="feed_twin.ros.sim_node",
            hostable=True,
            repeatable=False,
            guarded=True,
            own_node=True,
            topics=(
                _in("drive_command", msg_types.DRIVE_COMMAND),
                _in("program_state", msg_types.STRING),
                _out("feedback", msg_types.AXIS_FEEDBACK),
                _out("state", msg_types.AXIS_STATE),
                _out("joint_states", msg_types.JOINT_STATE),
                _out("run_state", msg_types.STRING),
                _out("health", msg_types.HEALTH_STATUS),
                *_LIVENESS,
            ),
            arguments=("--realtime", "--max-time", "--axis-clock", PEER_TIMEOUT),
        ),
        Role(
            name="gcode",
            node_name="gcode",
            module="feed_twin.ros.gcode_node",
            hostable=True,
            repeatable=False,
            guarded=False,
            own_node=True,
            machine_wide=True,  # a machine's one NC serves every axis
            topics=(
                _out("command", msg_types.AXIS_COMMAND),
                _out("command_batch", msg_types.RECORD_BATCH),
                _out("program_state", msg_types.STRING),
                _in("run_state", msg_types.STRING),  # and the global /clock
                *_LIVENESS,
            ),
            arguments=(
                "--program",
                "--autostart",
                "--optional-stop",
                "--axis-clock",
                "--command-batch",
                *MACHINE_ARGUMENTS,
            ),  # fmt: skip
        ),
        Role(
            name="twin",
            node_name="twin",
            module="feed_twin.ros.twin_node",
            hostable=False,
            repeatable=False,
            guarded=False,
            own_node=True,
            # under the twin's own namespace (feed_twin.shadow.replay.twin_namespace); it reads
            # the measured axis's command and joint states by the names its map gives
            topics=(
                _out("state", msg_types.AXIS_STATE),
                _out("residual", msg_types.TWIN_RESIDUAL),
                _out("health", msg_types.HEALTH_STATUS),
                # state and residual packed beside the LinuxCNC bridge (twin_node --batch-topic)
                _out("batch", msg_types.RECORD_BATCH),
            ),
            arguments=(
                "--map",
                "--machine",
                "--axis",
                "--rrd",
                "--rerun-url",
                "--max-time",
                PEER_TIMEOUT,
                "--batch-topic",  # beside the LinuxCNC bridge
                "--nice",  # beside the LinuxCNC bridge: ros.linuxcnc_nice
            ),  # fmt: skip
        ),
        Role(
            name="standin",
            node_name="standin",
            module="feed_twin.ros.standin_node",
            hostable=False,
            repeatable=False,
            guarded=False,
            own_node=True,
            topics=(
                _in("command", msg_types.AXIS_COMMAND),  # --follow: the NC's
                _out("command", msg_types.AXIS_COMMAND),  # otherwise its own
                _out("joint_states", msg_types.JOINT_STATE),
                _out("run_state", msg_types.STRING),
                *_LIVENESS,
            ),
            arguments=(
                "--follow",
                "--machine",
                "--axis",
                "--realtime",
                "--duration",
                "--jitter",
                "--friction-scale",
                "--raise-friction-at",
                "--axis-clock",
                "--period",
                PEER_TIMEOUT,
            ),  # fmt: skip
        ),
        Role(
            name="linuxcnc",
            node_name="linuxcnc",
            module="feed_twin.ros.linuxcnc_node",
            hostable=False,
            repeatable=False,
            guarded=False,
            own_node=False,  # publishes no topic a guarded node reads
            # command, joint_states and servo packed (feed_twin/ros/linuxcnc_node.py)
            topics=(
                _out("linuxcnc/batch", msg_types.RECORD_BATCH),
                _out("run_state", msg_types.STRING),
                *_LIVENESS,
            ),
            arguments=("--program", "--nice"),
        ),
        Role(
            name="machine_linuxcnc",
            node_name="linuxcnc",
            module="feed_twin.ros.machine_linuxcnc_node",
            hostable=False,
            repeatable=False,
            guarded=False,
            own_node=False,
            machine_wide=True,  # one LinuxCNC for every axis of the machine
            # --nice: ros.linuxcnc_nice, as the single-axis bridge
            arguments=("--machine-config", "--axes", "--program", PEER_TIMEOUT, "--nice"),
        ),
    )
}


def node_role(name: str) -> Role:
    """The registry's entry for `name`; KeyError naming the known roles."""
    try:
        return ROLES[name]
    except KeyError:
        raise KeyError(f"node role {name!r}: must be one of {', '.join(ROLES)}") from None


def roles_where(**flags: bool) -> tuple[str, ...]:
    """The names of the roles whose flags (hostable, repeatable, guarded, own_node,
    machine_wide) have the given values, in registry order."""
    return tuple(
        r.name for r in ROLES.values() if all(getattr(r, k) == v for k, v in flags.items())
    )
