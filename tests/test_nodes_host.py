"""Several nodes in one process (feed_twin/ros/host.py) and the run's process layout."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import pytest
from nodes_support import AXIS_CONFIG, node_env

from feed_twin.launch.machine import machine_plan, machine_shadow_plan
from feed_twin.launch.plan import host_argv
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import load_run_config
from feed_twin.machine.nodes import NodePlan, node_plan
from feed_twin.machine.shadow_nodes import shadow_plan
from feed_twin.nodeset.config import load_node_set_config
from feed_twin.ros.domain import reserve_domain_id
from feed_twin.ros.host import split_argv, stops_at_first_failure


def test_a_host_command_line_names_each_node_with_its_own_arguments() -> None:
    nodes = [("sim", ["--config", "a.yaml", "--realtime"]), ("recorder", ["--bag", "b"])]
    assert split_argv(host_argv(nodes)) == nodes
    assert host_argv(nodes) == ["sim", "--config", "a.yaml", "--realtime", "--and", "recorder",
                                "--bag", "b"]  # fmt: skip


def test_a_host_takes_a_controller_node_per_axis() -> None:
    # a machine's controller process: one controller node per axis file (namespace)
    nodes = [
        ("controller", ["--config", "axis_x.yaml"]),
        ("controller", ["--config", "axis_y.yaml"]),
    ]
    assert split_argv(host_argv(nodes)) == nodes


def test_a_host_ends_at_its_first_failure_unless_it_holds_the_recorder() -> None:
    assert stops_at_first_failure(["controller", "controller", "controller"])
    assert stops_at_first_failure(["sim", "controller"])  # ros.controller_processes: with_sim
    assert not stops_at_first_failure(["recorder", "gcode"])
    assert not stops_at_first_failure(["sim", "recorder"])  # a single axis's sim + recorder
    assert not stops_at_first_failure(["sim"])


# Two nodes of one role in one process, as a machine's controllers: X's fails at once, Y's
# would run until stopped; the process must end at X's failure with its code.
ONE_ROLE_HOST = """
import time
from feed_twin.ros.dds import init_context
from feed_twin.ros.runtime import EXIT_ERROR, FeedTwinNode, NodeOptions, spin_nodes
context = init_context()
nodes = [FeedTwinNode("controller", NodeOptions(machine="cnc", axis=a, peers=()), context=context)
         for a in ("x", "y")]
nodes[0].finish(EXIT_ERROR, "controller: at t = 0.5 s: broken")
started = time.monotonic()
code = spin_nodes(nodes, context, until_all_done=True, stop_on_failure=True)
print("RESULT", code, [n.exit_code for n in nodes], round(time.monotonic() - started, 2))
"""


@pytest.mark.ros
def test_nodes_of_one_role_in_one_process_end_it_at_the_first_failure() -> None:
    with reserve_domain_id() as domain:
        done = subprocess.run(
            [sys.executable, "-c", ONE_ROLE_HOST], env=node_env(domain.domain_id),
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    line = next(ln for ln in done.stdout.splitlines() if ln.startswith("RESULT"))
    result = re.match(r"RESULT (\d+) \[1, (\w+)\] ([\d.]+)", line)
    assert result is not None, line
    code, y_code, seconds = result.groups()
    assert (int(code), y_code) == (1, "None"), line  # Y was still running: not waited for
    assert float(seconds) < 2.0
    assert "controller: at t = 0.5 s: broken" in done.stderr


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sim", "--and"], r"an empty node between '--and' separators"),
        (["planner", "--config", "a.yaml"], r"node role 'planner': must be one of recorder, "),
        (["sim", "--and", "sim"], r"node role 'sim' given twice"),
        ([], r"an empty node"),
    ],
)
def test_a_bad_host_command_line_says_what_is_wrong(argv: list[str], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        split_argv(argv)


def test_a_bad_host_command_line_exits_with_one_line() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "feed_twin.ros.host", "planner"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        "node host: node role 'planner': must be one of recorder, controller, sim, gcode"
    ]


def _processes(request: RunRequest, plan: NodePlan) -> dict[str, tuple[str, ...]]:
    return {p.name: p.roles for p in machine_plan(plan, request, Path("b")).processes}


def test_the_recorder_records_in_the_sims_process_in_lockstep_unless_configured_otherwise(
    tmp_path,
) -> None:
    assert load_node_set_config(AXIS_CONFIG).recorder_host == "auto"
    plan = node_plan(load_run_config(AXIS_CONFIG))  # the axis's node set: a one-axis machine
    assert (plan.axis_file, plan.recorder_with) == (True, "auto")
    lockstep = RunRequest(config=AXIS_CONFIG, program=Path("p.ngc"))
    realtime = dataclasses.replace(lockstep, realtime=True)
    external = dataclasses.replace(lockstep, no_gcode=True, program=None)
    together = {"controller": ("controller",), "sim": ("sim", "recorder"), "gcode": ("gcode",)}
    apart = {r: (r,) for r in ("recorder", "controller", "sim", "gcode")}
    assert _processes(lockstep, plan) == together
    assert _processes(realtime, plan) == apart  # the sim must not wait for bag writing
    assert _processes(lockstep, dataclasses.replace(plan, recorder_with="own")) == apart
    assert _processes(realtime, dataclasses.replace(plan, recorder_with="sim")) == together
    assert _processes(external, plan) == {"controller": ("controller",), "sim": ("sim", "recorder")}
    shadow = dataclasses.replace(lockstep, shadow=True)
    axis = shadow_plan(load_run_config(AXIS_CONFIG), tmp_path / "b")
    shadow_processes = {
        p.name: p.roles for p in machine_shadow_plan(axis, shadow, tmp_path / "b").processes
    }
    assert shadow_processes == {r: (r,) for r in ("recorder", "twin", "standin", "gcode")}
