"""The executors of a run plan (feed_twin.launch): its processes watched by `launch`, or all
its nodes in this process on one executor.

The machine in-process run needs no plan (feed_twin.machine.run_cli: the engines, no nodes).
"""

from __future__ import annotations

import sys
from pathlib import Path

from feed_twin.launch.plan import RunPlan
from feed_twin.ros.launch import Launched, launch


def run_processes(
    plan: RunPlan,
    logs: Path,
    env: dict[str, str],
    *,
    quiet: bool,
    total_s: float | None = None,
    deadline_s: float | None = None,
) -> Launched:
    """Start every process of `plan` and watch them until all have ended (feed_twin.ros.launch:
    a failure ends the run, at once with the plan's `stop_on_failure`); the clock process's log
    shows progress unless `quiet`, `total_s` [s simulated] its 100 %. Discovery stays on this
    host unless `env` says otherwise."""
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return launch(
        plan.commands(sys.executable), logs, env=env, progress_role=plan.clock,
        show_progress=not quiet, stop_on_failure=plan.stop_on_failure, deadline_s=deadline_s,
        progress_total_s=total_s,
    )  # fmt: skip


def run_in_this_process(plan: RunPlan) -> tuple[int, list]:
    """Every node of `plan`, built by its own module from its arguments, spun on one executor
    in this process until all are done; (exit code, the nodes)."""
    from feed_twin.ros.dds import init_context
    from feed_twin.ros.host import build_nodes
    from feed_twin.ros.runtime import spin_nodes

    context = init_context()
    nodes = build_nodes([(n.role, n.argv) for n in plan.nodes()], context)
    return spin_nodes(nodes, context, until_all_done=True), nodes
