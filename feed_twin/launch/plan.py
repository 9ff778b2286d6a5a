"""A run plan: the processes of a run, each hosting one or more node specs.

A `NodeSpec` is a role of the registry (feed_twin.nodeset.roles) with the arguments of its node
module. A `ProcessSpec` is one OS process: one node runs as `python -m <its module>`, several
share one process and one DDS participant through the node host (`HOST_MODULE`, which takes
only hostable roles, and a role twice only where the registry says it is repeatable). A
`RunPlan` lists the processes in start order and names the one whose log carries the run's
clock (its `STAGE`, `PROGRESS` and `TIMING` lines).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from feed_twin.nodeset.roles import HOST_MODULE, HOST_SEPARATOR, node_role


def host_argv(nodes: Sequence[tuple[str, Sequence[str]]]) -> list[str]:
    """The node host's command line for (role, node arguments) pairs (feed_twin/ros/host.py)."""
    argv: list[str] = []
    for role, args in nodes:
        argv += ([HOST_SEPARATOR] if argv else []) + [role, *args]
    return argv


@dataclass(frozen=True, kw_only=True)
class NodeSpec:
    """One node: its role and the arguments of its node module."""

    role: str
    argv: tuple[str, ...]

    def __post_init__(self) -> None:
        node_role(self.role)  # KeyError naming the known roles


@dataclass(frozen=True, kw_only=True)
class ProcessSpec:
    """One process (its name is its log's) and the nodes it hosts, in start order."""

    name: str
    nodes: tuple[NodeSpec, ...]

    def __post_init__(self) -> None:
        if not self.nodes:
            raise ValueError(f"process {self.name!r}: hosts no node")
        if len(self.nodes) == 1:
            return
        seen: set[str] = set()
        for node in self.nodes:
            role = node_role(node.role)
            if not role.hostable:
                raise ValueError(
                    f"process {self.name!r}: role {node.role!r} runs in a process of its own "
                    "(not hostable)"
                )
            if node.role in seen and not role.repeatable:
                raise ValueError(f"process {self.name!r}: role {node.role!r} given twice")
            seen.add(node.role)

    @property
    def roles(self) -> tuple[str, ...]:
        return tuple(n.role for n in self.nodes)

    def command(self, python: str) -> list[str]:
        """The command line: the node's own module, or the node host for several."""
        if len(self.nodes) == 1:
            node = self.nodes[0]
            return [python, "-m", node_role(node.role).module, *node.argv]
        return [python, "-m", HOST_MODULE, *host_argv([(n.role, n.argv) for n in self.nodes])]


@dataclass(frozen=True, kw_only=True)
class RunPlan:
    """The processes of a run in start order; `clock`: the process whose log reports the
    run's simulated time and timing (None: none started here); `stop_on_failure`: one process
    failing stops the others at once (a machine's axes do not watch each other's nodes)."""

    processes: tuple[ProcessSpec, ...]
    clock: str | None
    stop_on_failure: bool = False

    def __post_init__(self) -> None:
        names = [p.name for p in self.processes]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"run plan: process {', '.join(twice)} given twice")
        if self.clock is not None and self.clock not in names:
            raise ValueError(
                f"run plan: clock process {self.clock!r} is not one of {', '.join(names)}"
            )

    @classmethod
    def of(
        cls,
        processes: Mapping[str, Sequence[tuple[str, Sequence[str]]]],
        *,
        clock: str | None,
        stop_on_failure: bool = False,
    ) -> RunPlan:
        """From process name -> its (role, arguments) pairs."""
        return cls(
            processes=tuple(
                ProcessSpec(
                    name=name,
                    nodes=tuple(NodeSpec(role=r, argv=tuple(a)) for r, a in nodes),
                )
                for name, nodes in processes.items()
            ),
            clock=clock,
            stop_on_failure=stop_on_failure,
        )

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.processes)

    def process(self, name: str) -> ProcessSpec:
        for p in self.processes:
            if p.name == name:
                return p
        raise KeyError(f"run plan: no process {name!r} (processes: {', '.join(self.names)})")

    def clock_log(self, logs: Mapping[str, Path]) -> Path | None:
        """The clock process's log among a launch's `logs` (None: no clock here)."""
        return logs[self.clock] if self.clock is not None else None

    def nodes(self) -> tuple[NodeSpec, ...]:
        """Every node of the run, in start order (the single-process executor's list)."""
        return tuple(n for p in self.processes for n in p.nodes)

    def commands(self, python: str) -> dict[str, list[str]]:
        """Process name -> its command line."""
        return {p.name: p.command(python) for p in self.processes}

    def only(self, names: Iterable[str]) -> RunPlan:
        """The plan of the processes `names` started here (the others run elsewhere, `--start`);
        its clock is the first of them whose first node has the clock process's first role
        (another axis's sim), or None."""
        chosen = set(names)
        kept = tuple(p for p in self.processes if p.name in chosen)
        clock = None
        if self.clock is not None:
            role = self.process(self.clock).nodes[0].role
            clock = next((p.name for p in kept if p.nodes[0].role == role), None)
        return RunPlan(processes=kept, clock=clock, stop_on_failure=self.stop_on_failure)
