"""`feed-twin run PROGRAM --config MACHINE.yaml --shadow`: the machine's shadow twin as nodes.

1. Checks before anything moves (one line each): the machine file, `--axes`, the program on the
   machine's NC, every axis's `shadow:` section, and every axis file its nodes will read as a
   single-axis `run --shadow` would (feed_twin/ros/preflight.py).
2. Starts the recorder with the G-code node in its process, and per simulated axis a stand-in
   and a twin node, each in its own process (feed_twin.machine.shadow_nodes), in the run's own
   ROS domain with its run token; one process that fails stops the others at once, the
   recorder last, and the reason names the axis.
3. Afterwards: the bag (recovered if needed), per axis the shadow dashboard its twin wrote
   (`<bag>_<axis>.rrd`; with `--live` each twin streams it to the viewer while it runs, a
   recording per axis), and per axis the residuals and health (feed_twin.machine.shadow.
   axis_figures: FE and effort deviation RMS, worst health level, first warning, the named
   effect) in the summary and under "shadow" in the `--json` line, as `--in-process --shadow`
   gives them.

`--nc linuxcnc` puts LinuxCNC in the stand-ins' place (feed_twin/ros/machine_linuxcnc_node.py).

An axis file (`feed-twin run PROGRAM [--config AXIS.yaml] --shadow [--nc linuxcnc]`) runs here
as its one-axis machine, planned as the single-axis run had it
(feed_twin.machine.shadow_nodes.ShadowPlan.axis_file: `/clock`, processes named by role, no
stop on a first failure, `--realtime` allowed, LinuxCNC's single-axis bridge) and records the
same messages; its checks before the run and its figures are feed_twin.ros.axis_shadow's.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.launch.machine import machine_shadow_plan
from feed_twin.launch.plan import RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.shadow_nodes import ShadowPlan, shadow_plan
from feed_twin.nodeset.config import load_node_set_config
from feed_twin.nodeset.run_report import (
    RunReport,
    RunTiming,
    early_error_report,
    emit,
    mode_name,
    ros_domain,
    shown,
)
from feed_twin.ros import axis_shadow, preflight
from feed_twin.ros.launch import (
    foreign_messages,
    log_record,
    planned_duration_s,
    slow_line,
    slow_nodes,
)
from feed_twin.ros.machine_run import check_plan, make_readable, run_reserved

# the node set plays the program in lockstep, all axes in one bag, started here
REFUSED = ("single_process", "no_gcode", "realtime", "start")


def refused_options(args: argparse.Namespace) -> str:
    """The one-line refusal of options the machine's shadow nodes do not take ("" if none)."""
    refused = [f"--{o.replace('_', '-')}" for o in REFUSED if getattr(args, o, None)]
    if not refused:
        return ""
    return f"{', '.join(refused)}: not available for a machine's shadow node set"


def run_machine_shadow(args: argparse.Namespace, machine: MachineConfig) -> int:
    """The run (module docstring); returns the exit code."""
    planned = _plan(args, machine)
    if isinstance(planned, str):
        return _error(args, machine, planned)
    plan, run = planned
    bag, logs = args.out / args.name, args.out / f"{args.name}.logs"
    env = dict(os.environ)
    try:
        reservation = preflight.run_environment(args, env)
    except (ValueError, RuntimeError) as exc:
        return _error(args, machine, str(exc))
    settle = load_node_set_config(args.config).settle_s if plan.axis_file else 0.0
    total = planned_duration_s(args.program, machine.nc, settle_s=settle, json_out=args.json)
    result = run_reserved(run, logs, env, reservation, quiet=args.json, total_s=total)
    problem, recovered = make_readable(bag)
    summary = None
    if not problem:
        summary, problem = _finish(args, plan, bag, logs)
    code = preflight.exit_status(result.code) if result.code else int(summary is None)
    reason = _named(result.reason, plan)
    clock_log = run.clock_log(result.logs)
    bridge_said = (log_record(clock_log, "LINUXCNC") or {}) if plan.linuxcnc else {}
    if reason and bridge_said.get("fault"):
        reason = bridge_said["fault"]  # the bridge's own line for a LinuxCNC fault
    reason = preflight.with_disk_full(reason, bag)
    if code == 130:
        print("feed-twin run: interrupted: the figures below cover the run until the stop")
    for said in (reason, problem, slow_line(logs)):
        if said:
            print(f"feed-twin run: {said}", file=sys.stderr)
    for rrd in [plan.rrd(bag, a) for a in plan.axes]:
        preflight.remove_incomplete_rrd(rrd)
    timing = log_record(clock_log, "TIMING") or {}
    if plan.linuxcnc and not timing:
        timing = axis_shadow.linuxcnc_timing(bridge_said)
    foreign = foreign_messages(result.logs.values())
    for line in foreign.lines():
        print(line)  # the run's own output names who sent what it dropped
    figures, lines = _figures(plan, bag, summary, bridge_said)
    run_timing = RunTiming.from_report(timing)
    samples = run_timing.steps if run_timing.steps is not None else figures.get("samples")
    report = RunReport(
        mode=mode_name(args, machine=not plan.axis_file),
        exit_code=code,
        reason=reason or problem,
        bag=preflight.shown_output(bag),
        bag_recovered_messages=recovered,
        logs=str(logs),
        ros_domain=ros_domain(env),
        samples=samples,
        timing=run_timing,
        figures=figures if plan.axis_file else {"processes": list(run.names), **figures},
        figure_lines=tuple(lines),
        foreign_messages=foreign.as_dict(),
        slow_nodes=slow_nodes(logs),
        **_dashboards(plan, bag),
    )
    return emit(report, json_out=args.json)


def _plan(args: argparse.Namespace, machine: MachineConfig) -> tuple[ShadowPlan, RunPlan] | str:
    """The checked plan of the run (its column maps written), or the one line why not."""
    axis_file = machine.axis_file
    problem = axis_shadow.refused_options(args) if axis_file else refused_options(args)
    if problem:
        return problem
    bag = args.out / args.name  # feed_twin.ros.preflight.run_name, before anything started
    linuxcnc = args.nc == "linuxcnc"
    try:
        # an axis file's LinuxCNC was checked before its program (axis_shadow.linuxcnc_precheck)
        problem = linuxcnc_precheck(args.program, machine) if linuxcnc and not axis_file else ""
        if problem:
            return problem
        if axis_file:
            axis_shadow.check_inputs(args)  # the file its nodes read, as it is
        plan = shadow_plan(machine, bag, linuxcnc=linuxcnc)
        if not axis_file:
            check_plan(machine, plan.files, shadow=True)
        return plan, machine_shadow_plan(plan, RunRequest.from_args(args), bag)
    except (ConfigError, ValueError, OSError) as exc:
        return str(exc)


def _finish(
    args: argparse.Namespace, plan: ShadowPlan, bag: Path, logs: Path
) -> tuple[axis_shadow.AxisShadowSummary | dict | None, str]:
    """The figures from the readable bag: an axis file's (feed_twin.ros.axis_shadow), or every
    axis's shadow figures."""
    if plan.axis_file:
        return axis_shadow.finish(args, plan, bag, logs)
    return finish(bag, plan)


def _figures(
    plan: ShadowPlan, bag: Path, summary: axis_shadow.AxisShadowSummary | dict | None, said: dict
) -> tuple[dict, list[str]]:
    """The report's figures and the summary's lines: an axis file's as the single-axis run gave
    them; a machine's per axis, with LinuxCNC's side."""
    if isinstance(summary, axis_shadow.AxisShadowSummary):
        return summary.as_dict(), summary.format().splitlines()
    if plan.axis_file:
        return {}, []
    bridge = linuxcnc_figures(bag, plan, said, summary) if plan.linuxcnc and summary else None
    lines: list[str] = []
    if summary is not None:  # (with --live every twin streamed its dashboard as it ran)
        lines = figure_lines(plan, summary)
    if bridge is not None:
        lines += bridge_lines(bridge, said)
    extra = {"linuxcnc": bridge} if bridge else {}
    return {"axes": [a.lower() for a in plan.axes], "shadow": summary, **extra}, lines


def _dashboards(plan: ShadowPlan, bag: Path) -> dict:
    """The report's dashboard fields: an axis file's `.rrd` and column map, a machine's `.rrd`
    per axis."""
    if plan.axis_file:
        column_map = axis_shadow.column_map(plan)
        return {
            "rrd": preflight.shown_output(plan.rrd(bag, plan.axes[0]), rrd=True),
            "column_map": str(column_map) if column_map.exists() else None,
        }
    return {
        "rrd_per_axis": {
            a.lower(): preflight.shown_output(plan.rrd(bag, a), rrd=True) for a in plan.axes
        }
    }


def linuxcnc_precheck(program: Path, machine: MachineConfig) -> str:
    """Why LinuxCNC cannot be this machine's NC and machine ("" when it can): not installed,
    a machine it lacks an axis of, a program only one of the two interpreters accepts."""
    from feed_twin.linuxcnc.host import LinuxcncError, check_installed
    from feed_twin.linuxcnc.machine_shadow import linuxcnc_machine
    from feed_twin.linuxcnc.summary import interpreters_disagree

    try:
        check_installed()
        nc, servo = linuxcnc_machine(machine)
        return interpreters_disagree(program, nc, servo) or ""
    except (LinuxcncError, OSError) as exc:
        return str(exc)


def linuxcnc_figures(bag: Path, plan: ShadowPlan, report: dict, figures: dict) -> dict:
    """LinuxCNC's side of the run: per axis its own largest following error (its servo samples
    in the bag) added to `figures`; the bridge's counts and latencies (its LINUXCNC report)."""
    from feed_twin.io.bag import BagReader
    from feed_twin.linuxcnc.machine import JOINT_AXES
    from feed_twin.linuxcnc.summary import counts_against_expected

    fields = [f"following_error[{JOINT_AXES.index(a)}]" for a in plan.axes]
    reader = BagReader(bag)
    servo = reader.columns(f"{plan.namespace(plan.axes[0])}/linuxcnc/servo", fields)
    for axis, field in zip(plan.axes, fields, strict=True):
        fe = servo[field]
        figures[axis.lower()]["linuxcnc_following_error_max_m"] = (
            float(np.max(np.abs(fe))) if fe.size else None
        )
    keys = ("program_time_s", "samples_received", "samples_published",
            "bridge_latency_p50_ms", "bridge_latency_p99_ms", "twin_output_latency_p50_ms",
            "twin_output_latency_p99_ms", "startup_s")  # fmt: skip
    bag_counts, lost_by_topic, lost = counts_against_expected(reader, report)
    return {**{k: report.get(k) for k in keys}, "samples_lost": lost, "bag_counts": bag_counts,
            "samples_lost_by_topic": lost_by_topic}  # fmt: skip


def bridge_lines(bridge: dict, report: dict) -> list[str]:
    """The summary's lines of LinuxCNC's side (`linuxcnc_figures`, the bridge's report)."""
    from feed_twin.linuxcnc.summary import servo_timing_from_report

    lines = [
        f"LinuxCNC: program time {shown(bridge['program_time_s'], 's')}, servo samples "
        f"{bridge['samples_received']} received, {bridge['samples_lost']} lost; bridge "
        f"latency p99 {shown(bridge['bridge_latency_p99_ms'], 'ms')}"
    ]
    if any(bridge["samples_lost_by_topic"].values()):
        lost = bridge["samples_lost_by_topic"].items()
        lines.append("samples lost by topic: " + ", ".join(f"{t} {n}" for t, n in lost))
    servo_timing = servo_timing_from_report(report)
    if servo_timing is not None:
        lines.append(servo_timing.format())
    return lines


def finish(bag: Path, plan: ShadowPlan) -> tuple[dict | None, str]:
    """Every axis's shadow figures read from the (readable) bag."""
    from feed_twin.io.bag import BagError
    from feed_twin.machine.shadow_nodes import read_shadow_bag

    try:
        return read_shadow_bag(bag, plan.machine, plan.axes, plan.effort_units), ""
    except (BagError, ValueError) as exc:
        return None, str(exc)


def figure_lines(plan: ShadowPlan, figures: dict[str, dict]) -> list[str]:
    from feed_twin.machine.shadow import format_axis_figures

    return [
        f"machine {plan.machine}: axes {', '.join(figures)} shadowed, each in its own nodes",
        *(
            f"{format_axis_figures(axis, f)} ({f['samples']} samples)"
            for axis, f in figures.items()
        ),
    ]


def _named(reason: str, plan: ShadowPlan) -> str:
    """The launcher's reason with the axis of the failed process named first."""
    from feed_twin.machine.nodes import axis_of_process

    axis = axis_of_process(reason.split(" ", 1)[0], plan.axes) if reason else None
    return f"axis {axis}: {reason}" if axis is not None else reason


def _error(args: argparse.Namespace, machine: MachineConfig, message: str) -> int:
    print(f"feed-twin run: {message}", file=sys.stderr)
    report = early_error_report(mode_name(args, machine=not machine.axis_file), message)
    return emit(report, json_out=getattr(args, "json", False))
