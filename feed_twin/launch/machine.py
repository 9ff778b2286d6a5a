"""The run plans of a machine's node sets: its node set (feed_twin.machine.nodes) and its shadow
node set (feed_twin.machine.shadow_nodes), as `RunPlan`s the executors run.

An axis file runs as its one-axis machine through the same two planners (NodePlan.axis_file,
ShadowPlan.axis_file). One process failing stops the others at once (`stop_on_failure`): an
axis's nodes do not watch the other axes' nodes (an axis file's one-axis machine: its nodes
watch each other, as they did). The clock is the first axis's sim (node set) or stand-in
(shadow), or LinuxCNC's bridge when LinuxCNC is the machine (an axis file's: the single-axis
bridge).
"""

from __future__ import annotations

from pathlib import Path

from feed_twin.launch.plan import RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.nodes import NodePlan, NodeRunOptions, chosen_processes
from feed_twin.machine.shadow_nodes import ShadowPlan

CLOCK_ROLES = ("sim", "standin", "machine_linuxcnc", "linuxcnc")  # the roles that pace a run


def _clock(processes: dict[str, list[tuple[str, list[str]]]]) -> str | None:
    return next((n for n, nodes in processes.items() if nodes[0][0] in CLOCK_ROLES), None)


def machine_plan(plan: NodePlan, request: RunRequest, bag: Path) -> RunPlan:
    """The machine's node set, only the processes `request.start` names (ValueError naming a
    name that is neither a process nor a role, feed_twin.machine.nodes.chosen_processes; and
    without a PROGRAM unless --no-gcode)."""
    options = NodeRunOptions(
        no_gcode=request.no_gcode,
        optional_stop=request.optional_stop,
        max_time_s=request.max_time_s,
        live_url=request.live_url,
    )
    processes = plan.processes(
        program=request.program,
        bag=bag,
        realtime=request.realtime,
        common=request.common_argv(),
        options=options,
    )
    here = chosen_processes(processes, request.start)
    # an axis file's nodes watch each other (NodePlan's docstring)
    stop = not plan.axis_file
    return RunPlan.of(processes, clock=_clock(processes), stop_on_failure=stop).only(here)


def machine_shadow_plan(plan: ShadowPlan, request: RunRequest, bag: Path) -> RunPlan:
    """The machine's shadow node set: per axis a stand-in (or LinuxCNC for all) and a twin."""
    if request.program is None:
        raise ValueError("a machine's shadow node set needs a PROGRAM")
    processes = plan.processes(
        program=request.program,
        bag=bag,
        common=request.common_argv(),
        live_url=request.live_url,
        realtime=request.realtime,
        optional_stop=request.optional_stop,
    )
    # an axis file's nodes watch each other (ShadowPlan's docstring)
    stop = not plan.axis_file
    return RunPlan.of(processes, clock=_clock(processes), stop_on_failure=stop)
