"""The run plan (feed_twin.launch): a plan's processes, their command lines, every axis mode's
nodes, and the refusals of a plan that cannot run. Plain data, no ROS."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import pytest

from feed_twin.launch.machine import machine_plan, machine_shadow_plan
from feed_twin.launch.plan import NodeSpec, ProcessSpec, RunPlan, host_argv
from feed_twin.launch.request import NCS, RunRequest
from feed_twin.machine.config import load_run_config
from feed_twin.machine.nodes import node_plan
from feed_twin.machine.shadow_nodes import shadow_plan
from feed_twin.nodeset.roles import COMMON_ARGUMENTS, HOST_MODULE, node_role

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
REQUEST = RunRequest(config=AXIS, program=Path("p.ngc"))


def axis_shadow_plan(request: RunRequest, bag: Path) -> RunPlan:
    """The shadow node set of the axis file: its one-axis machine's (writes its column map)."""
    plan = shadow_plan(load_run_config(AXIS), bag, linuxcnc=request.nc == "linuxcnc")
    return machine_shadow_plan(plan, request, bag)


def _spec(role: str, *argv: str) -> NodeSpec:
    return NodeSpec(role=role, argv=argv)


def test_one_node_runs_its_module_and_several_share_the_host() -> None:
    alone = ProcessSpec(name="gcode", nodes=(_spec("gcode", "--program", "p.ngc"),))
    assert alone.command("py") == ["py", "-m", "feed_twin.ros.gcode_node", "--program", "p.ngc"]
    shared = ProcessSpec(name="sim", nodes=(_spec("sim", "--realtime"), _spec("recorder", "-b")))
    assert shared.command("py") == ["py", "-m", HOST_MODULE, "sim", "--realtime", "--and",
                                    "recorder", "-b"]  # fmt: skip
    assert shared.roles == ("sim", "recorder")
    assert host_argv([("sim", ["--realtime"])]) == ["sim", "--realtime"]


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: _spec("planner"), "node role 'planner': must be one of recorder, controller"),
        (lambda: ProcessSpec(name="p", nodes=()), "process 'p': hosts no node"),
        (
            lambda: ProcessSpec(name="p", nodes=(_spec("twin"), _spec("recorder"))),
            "process 'p': role 'twin' runs in a process of its own (not hostable)",
        ),
        (
            lambda: ProcessSpec(name="p", nodes=(_spec("sim"), _spec("sim"))),
            "process 'p': role 'sim' given twice",
        ),
        (
            lambda: RunPlan.of({"a": [("sim", [])], "b": [("gcode", [])]}, clock="c"),
            "run plan: clock process 'c' is not one of a, b",
        ),
        (
            lambda: RunPlan(
                processes=(ProcessSpec(name="a", nodes=(_spec("sim"),)),) * 2, clock=None
            ),  # fmt: skip
            "run plan: process a given twice",
        ),
        (
            lambda: RunPlan.of({"a": [("sim", [])]}, clock="a").process("b"),
            "run plan: no process 'b' (processes: a)",
        ),
        (
            # the bad value under test
            lambda: RunRequest(config=AXIS, program=None, nc="fanuc"),  # pyright: ignore[reportArgumentType]
            "nc = 'fanuc': must be one",
        ),
        (
            lambda: dataclasses.replace(node_plan(load_run_config(AXIS)), recorder_with="disk"),
            "recorder_with = 'disk': must be one of gcode, sim, own, auto",
        ),
        (
            lambda: machine_plan(
                node_plan(load_run_config(AXIS)), RunRequest(config=AXIS, program=None), Path("b")
            ),
            "a node set needs a PROGRAM (or --no-gcode)",
        ),
        (
            lambda: RunRequest(config=AXIS, program=None, startup_timeout_s=0.0),
            "startup_timeout_s = 0.0: must be > 0",
        ),
        (
            lambda: RunRequest(config=AXIS, program=None, input_timeout_s=-1.0),
            "input_timeout_s = -1.0: must be > 0",
        ),
    ],
)
def test_a_plan_that_cannot_run_is_refused_naming_what(build, message) -> None:
    with pytest.raises(
        (ValueError, KeyError), match=message.replace("(", r"\(").replace(")", r"\)")
    ):
        build()


def test_a_repeatable_role_may_run_twice_in_one_process() -> None:
    controllers = ProcessSpec(name="c", nodes=(_spec("controller", "-x"), _spec("controller")))
    assert controllers.roles == ("controller", "controller")


def test_the_lockstep_axis_run_records_in_the_sims_process() -> None:
    """An axis's node set is its one-axis machine's plan, with the nodes of the axis run."""
    plan = machine_plan(node_plan(load_run_config(AXIS)), REQUEST, Path("out/run"))
    assert plan.names == ("controller", "sim", "gcode") and plan.clock == "sim"
    assert not plan.stop_on_failure  # the axis's nodes watch each other
    sim = plan.process("sim")
    assert sim.roles == ("sim", "recorder")
    assert sim.nodes[1].argv == (
        "--config", str(AXIS), "--peers", "gcode,controller,sim", "--startup-timeout", "120.0",
        "--input-timeout", "10.0", "--machine-axes", "", "--command-axes", "", "--bag", "out/run",
    )  # fmt: skip
    # the sim publishes /clock (no --axis-clock) and the G-code node commands X alone
    assert plan.process("sim").nodes[0].argv[-1] == "10.0"
    assert "--axis-clock" not in plan.process("gcode").nodes[0].argv
    # one process: every node in plan order
    assert [n.role for n in plan.nodes()] == ["controller", "sim", "recorder", "gcode"]


def test_each_mode_starts_its_roles_with_its_clock(tmp_path) -> None:
    """An axis's shadow node set is its one-axis machine's plan, with the nodes, processes,
    arguments and files of the single-axis shadow run."""
    bag = tmp_path / "run"
    shadow = dataclasses.replace(REQUEST, shadow=True)
    linuxcnc = dataclasses.replace(shadow, nc="linuxcnc")
    plan = axis_shadow_plan(shadow, bag)
    assert plan.names == ("recorder", "twin", "standin", "gcode") and plan.clock == "standin"
    assert not plan.stop_on_failure  # the axis's nodes watch each other
    assert plan.process("twin").nodes[0].argv == (
        "--config", str(AXIS), "--peers", "recorder,standin,gcode", "--startup-timeout", "120.0",
        "--input-timeout", "10.0", "--map", f"{bag}_map.yaml", "--machine", "cnc", "--axis", "x",
        "--rrd", f"{bag}.rrd",
    )  # fmt: skip
    assert (tmp_path / "run_map.yaml").is_file()
    # the stand-in publishes /clock (no --axis-clock) and paces by the wall clock when asked
    assert plan.process("standin").nodes[0].argv[-5:] == ("--follow", "--machine", "cnc",
                                                           "--axis", "x")  # fmt: skip
    paced = axis_shadow_plan(dataclasses.replace(shadow, realtime=True), bag)
    assert paced.process("standin").nodes[0].argv[-1] == "--realtime"
    assert axis_shadow_plan(linuxcnc, bag).names == ("recorder", "twin", "linuxcnc")
    assert axis_shadow_plan(linuxcnc, bag).clock == "linuxcnc"
    # beside LinuxCNC the bridge and the twin run with a larger share of a busy CPU
    beside = axis_shadow_plan(linuxcnc, bag)
    assert beside.process("twin").nodes[0].argv[-4:] == (
        "--batch-topic", "/cnc/x/linuxcnc/batch", "--nice", "-10",
    )  # fmt: skip
    assert beside.process("linuxcnc").nodes[0].argv[-2:] == ("--nice", "-10")
    assert "--nice" not in plan.process("twin").nodes[0].argv
    twin = axis_shadow_plan(dataclasses.replace(shadow, live_url="rerun+http://h"), bag)
    assert twin.process("twin").nodes[0].argv[-2:] == ("--rerun-url", "rerun+http://h")
    assert twin.process("recorder").nodes[0].argv[-2:] == ("--twin-namespace", "/cnc/x/twin")


def test_every_launch_argument_is_one_the_registry_declares_for_its_role(tmp_path) -> None:
    bag, machine = tmp_path / "run", load_run_config(AXIS)
    plans = {nc: shadow_plan(machine, bag, linuxcnc=nc == "linuxcnc") for nc in NCS}
    for request in _every_request():
        for node in machine_shadow_plan(plans[request.nc], request, bag).nodes():
            options = {a for a in node.argv if a.startswith("--")}
            allowed = set(COMMON_ARGUMENTS) | set(node_role(node.role).arguments)
            assert options <= allowed, (node.role, options - allowed)


def _every_request(shadow_only: bool = True):
    for shadow, nc, realtime, live, max_time, stop in itertools.product(
        (False, True), ("feed_twin", "linuxcnc"), (False, True), (None, "rerun+http://h"),
        (None, 2.5), (False, True),
    ):  # fmt: skip
        if (nc == "linuxcnc" or shadow_only) and not shadow:
            continue
        yield dataclasses.replace(
            REQUEST, shadow=shadow, nc=nc, realtime=realtime, live_url=live, max_time_s=max_time,
            optional_stop=stop,
        )  # fmt: skip


def test_only_keeps_the_named_processes_and_finds_their_clock() -> None:
    plan = RunPlan.of(
        {"recorder": [("recorder", []), ("gcode", [])], "x_sim": [("sim", [])],
         "y_sim": [("sim", [])]},
        clock="x_sim", stop_on_failure=True,
    )  # fmt: skip
    elsewhere = plan.only(["recorder", "y_sim"])
    assert elsewhere.names == ("recorder", "y_sim") and elsewhere.clock == "y_sim"
    assert elsewhere.stop_on_failure
    assert plan.only(["recorder"]).clock is None
    assert plan.only(["recorder"]).clock_log({"recorder": Path("r.log")}) is None
    assert plan.clock_log({"x_sim": Path("x.log")}) == Path("x.log")


def test_every_machine_launch_argument_is_one_the_registry_declares(tmp_path) -> None:
    from feed_twin.launch.machine import machine_plan, machine_shadow_plan
    from feed_twin.machine.config import load_machine_config
    from feed_twin.machine.nodes import node_plan
    from feed_twin.machine.shadow_nodes import shadow_plan

    config = ROOT / "config" / "machine_default.yaml"
    machine = load_machine_config(config)
    request = RunRequest(
        config=config, program=Path("p.ngc"), realtime=True, live_url="rerun+http://h"
    )
    bag = tmp_path / "run"
    plans = [
        machine_plan(node_plan(machine, tmp_path), request, bag),
        machine_shadow_plan(shadow_plan(machine, bag), request, bag),
        machine_shadow_plan(shadow_plan(machine, bag, linuxcnc=True), request, bag),
    ]
    assert [p.clock for p in plans] == ["x_sim", "x_standin", "linuxcnc"]
    assert all(p.stop_on_failure for p in plans)
    # --live: the node set's recorder streams every axis, each shadow twin its dashboard
    recorder = next(n for n in plans[0].nodes() if n.role == "recorder")
    assert recorder.argv[-2:] == ("--live-url", "rerun+http://h")
    twins = [n for plan in plans[1:] for n in plan.nodes() if n.role == "twin"]
    assert len(twins) == 6 and all("rerun+http://h" in n.argv for n in twins)
    axis = node_plan(load_run_config(AXIS))  # every option of an axis's node set
    plans += [machine_plan(axis, r, bag) for r in _every_request(shadow_only=False) if not r.shadow]
    for plan in plans:
        for node in plan.nodes():
            options = {a for a in node.argv if a.startswith("--")}
            allowed = set(COMMON_ARGUMENTS) | set(node_role(node.role).arguments)
            assert options <= allowed, (node.role, options - allowed)


def test_beside_linuxcnc_a_machines_bridge_and_every_twin_run_at_its_nice(tmp_path) -> None:
    """ros.linuxcnc_nice reaches a machine's LinuxCNC bridge and each axis's twin through the
    shadow plan (the machine file's ros: section, or the default), as an axis file's does."""
    from feed_twin.machine.config import load_machine_config

    request = RunRequest(config=ROOT / "config" / "machine_default.yaml", program=Path("p.ngc"))
    bag = tmp_path / "run"

    def plan(path: Path, *, linuxcnc: bool) -> RunPlan:
        return machine_shadow_plan(
            shadow_plan(load_machine_config(path), bag, linuxcnc=linuxcnc), request, bag
        )

    def nice_of(plan: RunPlan) -> dict[str, str | None]:
        return {
            f"{name}/{node.role}": node.argv[node.argv.index("--nice") + 1]
            if "--nice" in node.argv else None
            for name in plan.names for node in plan.process(name).nodes
        }  # fmt: skip

    assert nice_of(plan(request.config, linuxcnc=True)) == {
        "recorder/recorder": None, "linuxcnc/machine_linuxcnc": "-10", "x_twin/twin": "-10",
        "y_twin/twin": "-10", "z_twin/twin": "-10",
    }  # fmt: skip
    # beside stand-ins nothing runs at another weight
    assert set(nice_of(plan(request.config, linuxcnc=False)).values()) == {None}
    # the machine file's own value, in its ros: section
    (tmp_path / "axis_default.yaml").write_text(AXIS.read_text())
    text = request.config.read_text().replace("\nros:\n", "\nros:\n  linuxcnc_nice: -5\n")
    mine = tmp_path / "machine.yaml"
    mine.write_text(text)
    assert set(nice_of(plan(mine, linuxcnc=True)).values()) == {None, "-5"}
