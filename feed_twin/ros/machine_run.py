"""`feed-twin run PROGRAM --config MACHINE.yaml`: the machine's node set (feed_twin.machine.nodes).

1. Checks before anything moves (one line each): the machine file, `--axes`, the program on the
   machine's NC, and every axis file its nodes will read as a single-axis run would
   (feed_twin/ros/preflight.py: sections, the controller at the exchange period, the drive's
   reach of the NC's limits).
2. Starts the recorder with the G-code node in its process, per simulated axis a sim node in
   its own process, and the controller nodes of every axis in one process (or each in its own,
   `ros.controller_processes: per_axis`), in the run's own ROS domain with its run token; one
   process that fails (an axis node killed, a drive fault) stops all others at once, the
   recorder last, and the reason names the axis (every axis of the controller process).
3. Afterwards: the `.rrd` dashboard (feed_twin.machine.dashboard, as in-process); the bag
   (recovered if needed) gets the contour error and its along-path lag per
   sample (`/<machine>/contour_error`, `/<machine>/contour_lag`, std_msgs/Float64 [m], logged at
   the first axis's state of the same sample), and the summary and `--json` give
   contour_error_max_m, contour_error_rms_m, following_error_max_m per axis and the timing of
   the first axis's sim (realtime_factor, lateness with --realtime).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from feed_twin.core.config import ConfigError
from feed_twin.io import msg_types
from feed_twin.io.live import show_recording
from feed_twin.launch.machine import machine_plan
from feed_twin.launch.plan import RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.nodes import RECORDER_PROCESS, NodePlan, node_plan, read_machine_bag
from feed_twin.nodeset.run_report import (
    RunReport,
    RunTiming,
    early_error_report,
    emit,
    mode_name,
    ros_domain,
)
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.ros import preflight
from feed_twin.ros.executors import run_processes
from feed_twin.ros.launch import (
    Launched,
    foreign_messages,
    log_record,
    planned_duration_s,
    slow_line,
    slow_nodes,
)

if TYPE_CHECKING:
    from feed_twin.ros.domain import DomainReservation

REFUSED = ("single_process", "no_gcode", "shadow")


def check_plan(machine: MachineConfig, files: Mapping[str, Path], *, shadow: bool = False) -> None:
    """Every axis file as its nodes will read it (ConfigError naming the axis); `shadow`: with
    its shadow: section."""
    for axis, path in files.items():
        try:
            preflight.check_run_config(path, shadow=shadow)
        except ConfigError as exc:
            # the written file is the machine file's axis: name that instead
            said = str(exc).removeprefix(f"{path}: ")
            raise ConfigError(f"{machine.source}: axis {axis}: {said}") from None


def run_machine_nodes(args: argparse.Namespace, machine: MachineConfig) -> int:
    """The run (module docstring); returns the exit code."""
    refused = [f"--{o.replace('_', '-')}" for o in REFUSED if getattr(args, o, False)]
    if refused:
        return _error(args, f"{', '.join(refused)}: not available for a machine's node set")
    name = args.name  # feed_twin.ros.preflight.run_name, before anything started
    bag, logs = args.out / name, args.out / f"{name}.logs"
    try:
        plan = node_plan(machine, settle_s=args.settle)
        check_plan(machine, plan.files)
        run = machine_plan(plan, RunRequest.from_args(args), bag)
    except (ConfigError, ValueError, OSError) as exc:
        return _error(args, str(exc))
    here = list(run.names)
    env = dict(os.environ)
    try:
        reservation = preflight.run_environment(args, env)
    except (ValueError, RuntimeError) as exc:
        return _error(args, str(exc))
    total = planned_duration_s(args.program, machine.nc, settle_s=args.settle, json_out=args.json)
    result = run_reserved(run, logs, env, reservation, quiet=args.json, total_s=total)
    timing = log_record(run.clock_log(result.logs), "TIMING") or {}
    summary, problem = None, ""
    if RECORDER_PROCESS in here:
        summary, problem = _finish(bag, machine, args.program)
        if summary is not None:
            show_recording(getattr(args, "live_viewer", None), bag.with_name(f"{bag.name}.rrd"))
    else:
        print(f"started here: {', '.join(here)}; the recorder runs elsewhere")
    failed = result.code != 0 or (summary is None and RECORDER_PROCESS in here)
    code = preflight.exit_status(result.code) if result.code else int(failed)
    reason = _with_trip_line(_named(result.reason, plan), bag, machine, args.program)
    foreign = foreign_messages(result.logs.values())
    for line in foreign.lines():
        print(line)  # the run's own output names who sent what it dropped
    for said in (reason, problem, slow_line(logs)):
        if said:
            print(f"feed-twin run: {said}", file=sys.stderr)
    run_timing = RunTiming.from_report(timing)
    report = RunReport(
        mode=mode_name(args, machine=True),
        exit_code=code,
        reason=reason or problem,
        bag=preflight.shown_output(bag),
        rrd=preflight.shown_output(bag.with_name(f"{bag.name}.rrd"), rrd=True),
        logs=str(logs),
        ros_domain=ros_domain(env),
        samples=run_timing.steps,
        timing=run_timing,
        figures={"processes": here, **(summary or {})},
        figure_lines=tuple(_figure_lines(machine, summary)) if summary is not None else (),
        foreign_messages=foreign.as_dict(),
        slow_nodes=slow_nodes(logs),
    )
    return emit(report, json_out=args.json)


def run_reserved(
    plan: RunPlan,
    logs: Path,
    env: dict[str, str],
    reservation: DomainReservation | None,
    *,
    quiet: bool,
    total_s: float | None = None,
) -> Launched:
    """Run `plan`'s processes (feed_twin.ros.executors.run_processes), then release the run's
    domain reservation."""
    try:
        return run_processes(plan, logs, env, quiet=quiet, total_s=total_s)
    finally:
        if reservation is not None:
            reservation.release()
        preflight.end_environment(env)


def _named(reason: str, plan: NodePlan) -> str:
    """The launcher's reason with the axes of the failed process named first."""
    if not reason:
        return reason
    axes = plan.axes_of_process(reason.split(" ", 1)[0])
    if not axes:
        return reason
    return f"axis {axes[0]}: {reason}" if len(axes) == 1 else f"axes {', '.join(axes)}: {reason}"


def _with_trip_line(reason: str, bag: Path, machine: MachineConfig, program: Path) -> str:
    """`reason` with the program line active at a drive fault's time added to the fault's
    line (feed_twin.nodeset.protection.describe_trip), read from the tripped axis's commands."""
    from feed_twin.io.bag import BagError, BagReader
    from feed_twin.nodeset.protection import describe_trip
    from feed_twin.ros.gcode_node import program_lines

    head, _, rest = reason.partition("\n")
    axis = head.removeprefix("axis ").partition(":")[0]
    if "drive fault " not in head or axis not in machine.axes or not bag.exists():
        return reason
    topic = AxisTopics(machine=machine.name, axis=axis.lower()).command
    try:
        run = {topic: BagReader(bag).columns(topic, ["header.stamp", "line"])}
    except (BagError, ValueError, OSError):
        return reason
    head = describe_trip(head, run, topic, program_lines(program))
    return f"{head}\n{rest}" if rest else head


def readable_bag(bag: Path) -> str:
    """ "" when the run's bag can be read (recovered first when the recording was cut short),
    else why not."""
    from feed_twin.io.bag import BagError, info, recover

    if not bag.exists():
        return "no bag was written"
    try:
        info(bag)
    except BagError:
        try:
            kept = recover(bag).messages_recovered
        except BagError as exc:
            return f"the bag is unreadable: {exc}"
        print(f"bag: the recording was incomplete; recovered {kept} messages")
    return ""


def _finish(bag: Path, machine: MachineConfig, program: Path) -> tuple[dict | None, str]:
    """The bag made readable, the contour error added to it, and the run's figures."""
    import numpy as np

    from feed_twin.gcode.geometry import programmed_path
    from feed_twin.io.bag import BagError, BagReader, add_topics
    from feed_twin.io.cdr import FlatCodec

    problem = readable_bag(bag)
    if problem:
        return None, problem
    try:
        record = read_machine_bag(bag, machine, programmed_path(program, machine.nc))
    except (BagError, ValueError) as exc:
        return None, str(exc)
    first = AxisTopics(machine=machine.name, axis=machine.simulated[0].lower()).state
    logged = BagReader(bag).columns(first, [])["log_time_s"][: len(record.t_s)]
    stamps = np.round(logged * 1e9).astype(np.int64)
    scalar = FlatCodec(msg_types.FLOAT64)
    add_topics(
        bag,
        {
            f"/{machine.name}/{name}": (
                msg_types.FLOAT64,
                [
                    (int(t), scalar.encode_map({"data": float(v)}))
                    for t, v in zip(stamps, column, strict=True)
                ],
            )
            for name, column in (
                ("contour_error", record.contour.normal_m),
                ("contour_lag", record.contour.lag_m),
            )  # fmt: skip
        },
    )
    from feed_twin.machine.dashboard import write_machine_dashboard

    segments = programmed_path(program, machine.nc)
    write_machine_dashboard(record, segments, bag.with_name(f"{bag.name}.rrd"))
    return record.summary(), ""


def _figure_lines(machine: MachineConfig, summary: dict) -> list[str]:
    from feed_twin.machine.run_cli import machine_figure_lines

    return [
        f"machine {machine.name}: {summary['simulated_s']:.3f} s simulated, axes "
        f"{', '.join(summary['axes'])} in their own nodes",
        *machine_figure_lines(summary),
    ]


def _error(args: argparse.Namespace, message: str) -> int:
    print(f"feed-twin run: {message}", file=sys.stderr)
    report = early_error_report(mode_name(args, machine=True), message)
    return emit(report, json_out=getattr(args, "json", False))
