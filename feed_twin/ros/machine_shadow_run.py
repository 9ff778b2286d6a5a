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

`--nc linuxcnc` puts LinuxCNC in the stand-ins' place (feed_twin/ros/machine_linuxcnc_run.py).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.launch.machine import machine_shadow_plan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.shadow_nodes import ShadowPlan, shadow_plan
from feed_twin.nodeset.run_report import (
    RunReport,
    RunTiming,
    early_error_report,
    emit,
    mode_name,
    ros_domain,
    shown,
)
from feed_twin.ros import preflight
from feed_twin.ros.launch import (
    foreign_messages,
    log_record,
    planned_duration_s,
    slow_line,
    slow_nodes,
)
from feed_twin.ros.machine_run import check_plan, readable_bag, run_reserved

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
    problem = refused_options(args)
    if problem:
        return _error(args, problem)
    name = args.name  # feed_twin.ros.preflight.run_name, before anything started
    bag, logs = args.out / name, args.out / f"{name}.logs"
    linuxcnc = args.nc == "linuxcnc"
    try:
        if linuxcnc:
            problem = linuxcnc_precheck(args.program, machine)
            if problem:
                return _error(args, problem)
        plan = shadow_plan(machine, bag, linuxcnc=linuxcnc)
        check_plan(machine, plan.files, shadow=True)
        run = machine_shadow_plan(plan, RunRequest.from_args(args), bag)
    except (ConfigError, ValueError, OSError) as exc:
        return _error(args, str(exc))
    env = dict(os.environ)
    try:
        reservation = preflight.run_environment(args, env)
    except (ValueError, RuntimeError) as exc:
        return _error(args, str(exc))
    total = planned_duration_s(args.program, machine.nc, json_out=args.json)
    result = run_reserved(run, logs, env, reservation, quiet=args.json, total_s=total)
    figures, problem = finish(bag, plan)
    code = preflight.exit_status(result.code) if result.code else int(figures is None)
    reason = _named(result.reason, plan)
    bridge_said = (log_record(run.clock_log(result.logs), "LINUXCNC") or {}) if linuxcnc else {}
    if reason and bridge_said.get("fault"):
        reason = bridge_said["fault"]  # the bridge's own line for a LinuxCNC fault
    for said in (reason, problem, slow_line(logs)):
        if said:
            print(f"feed-twin run: {said}", file=sys.stderr)
    timing = RunTiming.from_report(log_record(run.clock_log(result.logs), "TIMING") or {})
    bridge = linuxcnc_figures(bag, plan, bridge_said, figures) if linuxcnc and figures else None
    lines: list[str] = []
    if figures is not None:  # (with --live every twin streamed its dashboard as it ran)
        lines = figure_lines(plan, figures)
    if bridge is not None:
        lines += bridge_lines(bridge, bridge_said)
    foreign = foreign_messages(result.logs.values())
    for line in foreign.lines():
        print(line)  # the run's own output names who sent what it dropped
    extra = {"axes": [a.lower() for a in plan.axes], "shadow": figures}
    report = RunReport(
        mode=mode_name(args, machine=True),
        exit_code=code,
        reason=reason or problem,
        bag=preflight.shown_output(bag),
        rrd_per_axis={
            a.lower(): preflight.shown_output(plan.rrd(bag, a), rrd=True) for a in plan.axes
        },
        logs=str(logs),
        ros_domain=ros_domain(env),
        samples=timing.steps,
        timing=timing,
        figures={"processes": list(run.names), **extra, **({"linuxcnc": bridge} if bridge else {})},
        figure_lines=tuple(lines),
        foreign_messages=foreign.as_dict(),
        slow_nodes=slow_nodes(logs),
    )
    return emit(report, json_out=args.json)


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
    """The bag made readable and every axis's shadow figures read from it."""
    from feed_twin.io.bag import BagError
    from feed_twin.machine.shadow_nodes import read_shadow_bag

    problem = readable_bag(bag)
    if problem:
        return None, problem
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


def _error(args: argparse.Namespace, message: str) -> int:
    print(f"feed-twin run: {message}", file=sys.stderr)
    report = early_error_report(mode_name(args, machine=True), message)
    return emit(report, json_out=getattr(args, "json", False))
