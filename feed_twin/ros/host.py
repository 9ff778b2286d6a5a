"""One process hosting several feed_twin nodes: one ROS context, so one DDS participant.

Fast DDS hands a sample to a reader in the same process by a function call, and a writer in
another process sends one datagram to a participant however many of its readers want the
sample. In lockstep `feed-twin run` therefore starts the recorder inside the sim node's
process (`ros.recorder_host: auto` or `sim`), as a rosbag2 recorder is loaded into a component
container next to a high-rate publisher: the sim's feedback and state reach the recorder
without a socket, and the controller's DriveCommand is one datagram for both. On a virtual
machine a datagram that wakes a thread on another core is costly, and a recorder process of its
own would wake thousands of times a second (docs/performance.md). The price: killing this process
ends both nodes, and the runner recovers the bag (at most one flush period, 0.5 s, is lost).

    python -m feed_twin.ros.host ROLE [NODE ARGS...] [--and ROLE [NODE ARGS...]]...

Each role takes the arguments of its own node module; the process runs until every node in it
has finished and exits with the first non-zero code.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from feed_twin.nodeset.roles import HOST_SEPARATOR, ROLES, roles_where

# role -> its node module (feed_twin.nodeset.roles)
NODE_MODULES = {name: entry.module for name, entry in ROLES.items()}
AND = HOST_SEPARATOR  # separates the nodes on the command line (launch.plan.host_argv)
HOSTABLE = roles_where(hostable=True)  # built by node_main's configure/build
# Roles a process may host several times, each in another axis's namespace: a machine's one
# controller process holds every axis's controller node (feed_twin/machine/nodes.py).
REPEATABLE = roles_where(repeatable=True)


def split_argv(argv: Sequence[str]) -> list[tuple[str, list[str]]]:
    """(role, node arguments) pairs of a host command line; ValueError names what is wrong."""
    groups: list[list[str]] = [[]]
    for arg in argv:
        if arg == AND:
            groups.append([])
        else:
            groups[-1].append(arg)
    nodes: list[tuple[str, list[str]]] = []
    for group in groups:
        if not group:
            raise ValueError(f"an empty node between '{AND}' separators in {list(argv)}")
        role, *args = group
        if role not in HOSTABLE:
            raise ValueError(f"node role {role!r}: must be one of {', '.join(HOSTABLE)}")
        if role not in REPEATABLE and any(role == r for r, _ in nodes):
            raise ValueError(f"node role {role!r} given twice")
        nodes.append((role, args))
    return nodes


def stops_at_first_failure(roles: Sequence[str]) -> bool:
    """Whether a host of nodes with `roles` ends at its first failing node: a machine's
    controllers, or an axis's sim and controller, where one node failing is the run's failure
    and the runner should stop the run naming it at once, as for a process of that node alone.
    With the recorder (recorder + G-code) the nodes finish together: it records to the end."""
    return len(roles) > 1 and "recorder" not in roles


def build_nodes(nodes: Sequence[tuple[str, Sequence[str]]], context) -> list:
    """Build each node with its module's own argument parser and `build`, in `context`."""
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.ros.runtime import node_options, node_parser

    built = []
    for role, args in nodes:
        module = importlib.import_module(NODE_MODULES[role])
        parsed = node_parser(f"{role} node", module.configure).parse_args(list(args))
        ros = load_node_set_config(parsed.config)
        built.append(module.build(parsed, ros, node_options(parsed, ros), context))
    return built


def main(argv: Sequence[str] | None = None) -> int:
    from feed_twin.ros.runtime import EXIT_ERROR, start_node

    try:
        nodes = split_argv(sys.argv[1:] if argv is None else argv)
    except ValueError as exc:
        print(f"node host: {exc}", file=sys.stderr)
        return EXIT_ERROR
    prog = "node host (" + " + ".join(role for role, _ in nodes) + ")"
    return start_node(
        prog,
        lambda context: build_nodes(nodes, context),
        stop_on_failure=stops_at_first_failure([role for role, _ in nodes]),
    )


if __name__ == "__main__":
    sys.exit(main())
