"""The run plan of one axis's node set, in each mode of `feed-twin run`.

Roles by mode (the NC, and whether the stand-in machine and the shadow twin run):

    feed_twin NC           recorder, controller, sim, gcode
    feed_twin NC, shadow   recorder, twin, standin, gcode
    LinuxCNC, shadow       recorder, twin, linuxcnc

Each node runs in its own process (with `--single-process` all in this one, in role order),
except that in lockstep the recorder records inside the sim's process (`ros.recorder_host`
auto or sim; feed_twin/ros/host.py). The clock process is the one whose node paces the run:
the sim, the stand-in, or LinuxCNC's bridge. `--no-gcode` leaves the G-code node out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from feed_twin.launch.plan import NodeSpec, ProcessSpec, RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.nodeset.config import NodeSetConfig
from feed_twin.nodeset.topics import RECORDER_NODE, AxisTopics

AXIS_ROLES = (RECORDER_NODE, "controller", "sim", "gcode")


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
    every = ("recorder", "twin", "standin", "gcode") if request.shadow else AXIS_ROLES
    return tuple(r for r in every if not (r == "gcode" and request.no_gcode))


def clock_role(request: RunRequest) -> str:
    """The node that sets the pace and reports PROGRESS and TIMING."""
    if request.nc == "linuxcnc":
        return "linuxcnc"
    return "standin" if request.shadow else "sim"


def _recorder(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--bag", str(files.bag)]
    if request.live_url and not request.shadow:
        argv += ["--live-url", request.live_url]
    if request.shadow:
        from feed_twin.shadow.replay import twin_namespace

        command = AxisTopics(machine=ros.machine, axis=ros.axis).command
        argv += ["--twin-namespace", twin_namespace(command)]
    return argv


def _gcode(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--program", str(request.program), "--autostart"]
    return argv + (["--optional-stop"] if request.optional_stop else [])


def _sim(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--realtime"] if request.realtime else []
    if request.max_time_s is not None:
        argv += ["--max-time", str(request.max_time_s)]
    return argv


def _standin(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--follow", "--machine", ros.machine, "--axis", ros.axis]
    return argv + (["--realtime"] if request.realtime else [])


def _linuxcnc(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    return ["--program", str(request.program)]


def _twin(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> list[str]:
    argv = ["--map", str(files.map), "--machine", ros.machine, "--axis", ros.axis]
    argv += ["--rrd", str(files.rrd)]
    if request.nc == "linuxcnc":  # the bridge sends its periods packed (ros/linuxcnc_node.py)
        argv += ["--batch-topic", AxisTopics(machine=ros.machine, axis=ros.axis).bridge_batch]
    return argv + (["--rerun-url", request.live_url] if request.live_url else [])


# role -> its launch arguments beyond the common ones (feed_twin.nodeset.roles names them)
ARGUMENTS: dict[str, Callable[[RunRequest, NodeSetConfig, AxisRunFiles], list[str]]] = {
    "recorder": _recorder,
    "gcode": _gcode,
    "sim": _sim,
    "standin": _standin,
    "linuxcnc": _linuxcnc,
    "twin": _twin,
    "controller": lambda request, ros, files: [],
}


def node_spec(role: str, request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> NodeSpec:
    """The node of `role` with its arguments: the common ones, its peers, its own."""
    peers = ",".join(r for r in roles(request) if r != role)
    argv = ["--config", str(request.config), "--peers", peers, *request.common_argv()]
    return NodeSpec(role=role, argv=tuple(argv + ARGUMENTS[role](request, ros, files)))


def axis_plan(request: RunRequest, ros: NodeSetConfig, files: AxisRunFiles) -> RunPlan:
    """The processes of the run (module docstring)."""
    names = roles(request)
    nodes = {role: node_spec(role, request, ros, files) for role in names}
    own = ros.recorder_host == "own" or (ros.recorder_host == "auto" and request.realtime)
    # one process: the nodes in role order on one executor (the plan's nodes())
    alone = own or request.shadow or request.transport == "single_process"
    if alone or RECORDER_NODE not in names:
        processes = [ProcessSpec(name=r, nodes=(nodes[r],)) for r in names]
    else:
        processes = [
            ProcessSpec(
                name=r, nodes=(nodes[r], nodes[RECORDER_NODE]) if r == "sim" else (nodes[r],)
            )
            for r in names
            if r != RECORDER_NODE
        ]
    return RunPlan(processes=tuple(processes), clock=clock_role(request))
