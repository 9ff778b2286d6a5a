"""Only the run's own nodes command the axis: admission of command messages.

Two independent checks, because rclpy (Jazzy) hands a subscription callback no publisher
identity (its message info has timestamps and sequence numbers, not the writer's GID):
- per message, the run's signature (feed_twin.nodeset.auth): every node signs what it
  publishes with the run's key, which only the run's processes hold, and every receiver admits
  only messages whose signature checks, new ones (no replay) and unaltered. This keeps out
  another run, a replayed bag, a test tool, and a process that reads the topics and sends
  their messages again, altered or not;
- per publisher, the graph: every second a guarded node lists the publishers of its input
  topics (node name, namespace, endpoint GID) and reports each one that is not a node of the
  run, once, as a warning and a HealthStatus, and names it in the run's foreign messages.
Then every admitted message is checked for values a drive can take (finite, within absurdity
bounds); a malformed message is dropped with a warning, never a crash.

Pure: the ROS side (feed_twin.ros) passes decoded fields and graph entries in.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from feed_twin.nodeset.roles import node_role, roles_where

OPEN_NC_ENV = "FEED_TWIN_OPEN_NC"  # "1": AxisCommand comes from outside (an external NC)
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"  # rmw's name for a node not yet discovered

# Magnitudes no feed-axis command reaches; beyond them a value is garbage, not a setpoint.
ABSURD = {
    "position": 1.0e3,  # [m]
    "velocity": 1.0e2,  # [m/s]
    "acceleration": 1.0e4,  # [m/s^2]
    "torque": 1.0e5,  # [N m]
    "i_q": 1.0e4,  # [A]
    "i_d": 1.0e4,  # [A]
    "u_d": 1.0e4,  # [V]
    "u_q": 1.0e4,  # [V]
}
PROGRAM_WORDS = ("loaded", "running", "paused", "finished", "stopped", "error", "waiting")


def check_values(values: Mapping[str, float]) -> str | None:
    """Why a decoded command is not a usable setpoint (None: it is)."""
    for name, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name} = {value!r}"
        bound = ABSURD.get(name)
        if bound is not None and abs(value) > bound:
            return f"{name} = {value!r} beyond +/-{bound:g}"
    return None


def bounds_of(names: Sequence[str]) -> tuple[float, ...]:
    """The ABSURD bound of each of `names`, for `within_bounds` (every name must have one)."""
    unknown = [name for name in names if name not in ABSURD]
    if unknown:
        raise ValueError(f"no ABSURD bound for {', '.join(unknown)}")
    return tuple(ABSURD[name] for name in names)


def within_bounds(values: Sequence[float], bounds: Sequence[float]) -> bool:
    """`check_values`'s fast answer for the common case: every value within its bound. A NaN
    or infinite value fails (`abs(nan) <= b` is false, and every bound is finite), and so
    does any value beyond its bound: then `check_values` says why. Called per exchange:
    one C-level pass instead of a dict and a loop in Python."""
    return all(map(operator.le, map(abs, values), bounds))


def parse_program_state(text: str) -> tuple[str, int | None, str] | None:
    """(word, time [ns] or None, text) of a program_state message (its signature checked and
    taken off, feed_twin.nodeset.auth); None when it is malformed."""
    if len(text) > 4096:
        return None
    word, _, rest = text.partition(" ")
    if word not in PROGRAM_WORDS:
        return None
    if word in ("finished", "stopped"):
        stamp = rest.split(" ", 1)[0]
        if not stamp.isdigit():
            return None
        return word, int(stamp), text
    return word, None, text


# nodes of the run that serve every axis of a machine (feed_twin.nodeset.roles)
MACHINE_WIDE_NODES = frozenset(
    node_role(name).node_name for name in roles_where(machine_wide=True, own_node=True)
)


@dataclass(frozen=True, kw_only=True)
class Endpoint:
    """A publisher in the ROS graph."""

    node_name: str
    node_namespace: str
    gid: str  # the endpoint GID as dotted hex

    def describe(self) -> str:
        ns = self.node_namespace.rstrip("/")
        return f"node '{ns}/{self.node_name}' (publisher gid {self.gid})"


@dataclass
class CommandGuard:
    """Counts what a node refused and finds foreign publishers on its command topics."""

    own_nodes: frozenset[str]  # node names of the run (roles and their helper nodes)
    namespace: str  # the run's namespace, e.g. /cnc/x
    refused: dict[str, int] = field(default_factory=dict)  # reason kind -> count
    reported: set[str] = field(default_factory=set)  # GIDs already reported

    def refuse(self, kind: str) -> int:
        """Count one refused message; returns the count of this kind so far."""
        self.refused[kind] = self.refused.get(kind, 0) + 1
        return self.refused[kind]

    def foreign(self, endpoints: Iterable[Endpoint]) -> list[Endpoint]:
        """Publishers not of the run, each returned once (the first time it is seen)."""
        # A participant's node names arrive after its endpoints: until then rmw reports
        # _NODE_NAME_UNKNOWN_, which is judged at the next look, not taken for foreign.
        seen = [e for e in endpoints if e.node_name != UNKNOWN_NODE_NAME]
        names = [e.node_name for e in seen if self._own(e)]
        found = []
        for e in seen:
            # A node of the run's name twice (a second run, or a copy) is foreign too: the run
            # has one publisher per node and topic.
            own = self._own(e) and names.count(e.node_name) == 1
            if not own and e.gid not in self.reported:
                self.reported.add(e.gid)
                found.append(e)
        return found

    def _own(self, e: Endpoint) -> bool:
        namespace = e.node_namespace.rstrip("/")
        if namespace == self.namespace:
            return e.node_name in self.own_nodes
        # a machine's one G-code node commands every axis from another axis's namespace of the
        # same machine (feed_twin.machine.nodes)
        machine = self.namespace.rpartition("/")[0]
        return e.node_name in MACHINE_WIDE_NODES and namespace.rpartition("/")[0] == machine
