"""The run plan of one axis's shadow node set (`feed-twin run --shadow`, and `--nc linuxcnc`).

Roles by NC:

    feed_twin NC   recorder, twin, standin, gcode
    LinuxCNC       recorder, twin, linuxcnc

Each node runs in its own process. The clock process is the one whose node paces the run: the
stand-in, or LinuxCNC's bridge. An axis's node set without the shadow twin is its one-axis
machine's (feed_twin.machine.nodes, launch/machine.py).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from feed_twin.launch.plan import NodeSpec, ProcessSpec, RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.nodeset.config import NodeSetConfig
from feed_twin.nodeset.topics import AxisTopics


@dataclass(frozen=True, kw_only=True)
class AxisRunFiles:
    """Where an axis run writes: the bag, the .rrd, and (shadow) the column map."""

    bag: Path
    rrd: Path
    map: Path


def roles(request: RunRequest) -> tuple[str, ...]:
    """The run's node roles (module docstring), in start order."""
    if request.nc == "linuxcnc":
        return ("recorder", "twin", "linuxcnc")
    return ("recorder", "twin", "standin", "gcode")


def clock_role(request: RunRequest) -> str:
    """The node that sets the pace and reports PROGRESS and TIMING."""
    return "linuxcnc" if request.nc == "linuxcnc" else "standin"


def _recorder(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    from feed_twin.shadow.replay import twin_namespace

    command = AxisTopics(machine=ros.machine, axis=ros.axis).command
    return ["--bag", str(files.bag), "--twin-namespace", twin_namespace(command)]


def _gcode(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--program", str(request.program), "--autostart"]
    return argv + (["--optional-stop"] if request.optional_stop else [])


def _standin(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--follow", "--machine", ros.machine, "--axis", ros.axis]
    return argv + (["--realtime"] if request.realtime else [])


def _linuxcnc(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    return ["--program", str(request.program), "--nice", str(ros.linuxcnc_nice)]


def _twin(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--map", str(files.map), "--machine", ros.machine, "--axis", ros.axis]
    argv += ["--rrd", str(files.rrd)]
    if request.nc == "linuxcnc":  # the bridge sends its periods packed (ros/linuxcnc_node.py)
        argv += ["--batch-topic", AxisTopics(machine=ros.machine, axis=ros.axis).bridge_batch]
        argv += ["--nice", str(ros.linuxcnc_nice)]  # as the bridge's (ros/dds.py, set_nice)
    return argv + (["--rerun-url", request.live_url] if request.live_url else [])


# role -> its launch arguments beyond the common ones (feed_twin.nodeset.roles names them)
ARGUMENTS: dict[str, Callable[[RunRequest, NodeSetConfig, AxisRunFiles], list[str]]] = {
    "recorder": _recorder,
    "gcode": _gcode,
    "standin": _standin,
    "linuxcnc": _linuxcnc,
    "twin": _twin,
}


def node_spec(role: str, request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> NodeSpec:
    """The node of `role` with its arguments: the common ones, its peers, its own."""
    peers = ",".join(r for r in roles(request) if r != role)
    argv = ["--config", str(request.config), "--peers", peers, *request.common_argv()]
    return NodeSpec(role=role, argv=tuple(argv + ARGUMENTS[role](request, ros, files)))


def axis_plan(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> RunPlan:
    """The processes of the run, one per node (module docstring)."""
    processes = [
        ProcessSpec(name=role, nodes=(node_spec(role, request, ros, files),))
        for role in roles(request)
    ]
    return RunPlan(processes=tuple(processes), clock=clock_role(request))
