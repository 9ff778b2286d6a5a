"""`feed-twin run PROGRAM --config MACHINE.yaml`: the machine's node set (feed_twin.machine.nodes);
and an axis file's node set, as its one-axis machine (below).

1. Checks before anything moves (one line each): the machine file, `--axes`, the program on the
   machine's NC, every axis file its nodes will read (feed_twin/ros/preflight.py: sections,
   the controller at the exchange period, the drive's reach of the NC's limits) and room in
   --out for the bag.
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

An axis file (`feed-twin run PROGRAM [--config AXIS.yaml]`) runs the same way as a one-axis
machine whose nodes are the single-axis run's (feed_twin.machine.nodes.NodePlan: `/clock`, the
controller in its own process, the recorder in the sim's process in lockstep or its own,
`ros.recorder_host`), and records the same bytes as the axis-only runner did
(benchmarks/identity.py's bag hashes). It keeps the axis run's options (`--single-process`:
every node in this process on one executor; `--no-gcode`: the commands from an external NC;
`--live`: the recorder streams the dashboard while it records), its dashboard and figures
(feed_twin.nodeset.summary: cycle time, following error, peak current and velocity) and its
words: the reason names no axis and the nodes notice a lost peer by its heartbeat.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from feed_twin.core.config import ConfigError
from feed_twin.io import msg_types
from feed_twin.io.live import show_recording
from feed_twin.launch.machine import machine_plan
from feed_twin.launch.plan import RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.nodes import NodePlan, node_plan, read_machine_bag
from feed_twin.nodeset.config import load_node_set_config
from feed_twin.nodeset.foreign import ForeignLedger, merge
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
from feed_twin.ros.executors import run_in_this_process, run_processes
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
    # an axis file's one-axis machine keeps the single-axis run's options
    options = ("shadow",) if machine.axis_file else REFUSED
    refused = [f"--{o.replace('_', '-')}" for o in options if getattr(args, o, False)]
    if refused:
        return _error(args, f"{', '.join(refused)}: not available for a machine's node set")
    name = args.name  # feed_twin.ros.preflight.run_name, before anything started
    bag, logs = args.out / name, args.out / f"{name}.logs"
    try:
        plan = node_plan(machine, settle_s=args.settle)
        check_plan(machine, plan.files)
        preflight.check_output_dir(args.out, _bag_bytes(args, machine, plan))
        run = machine_plan(plan, RunRequest.from_args(args), bag)
    except (ConfigError, ValueError, OSError) as exc:
        return _error(args, str(exc))
    here = list(run.names)
    # one process: its nodes read the run's domain and key from this process's environment
    processes_env = dict(os.environ)
    env: MutableMapping[str, str] = os.environ if args.single_process else processes_env
    try:
        reservation = preflight.run_environment(args, env)
    except (ValueError, RuntimeError) as exc:
        return _error(args, str(exc))
    if args.single_process:
        ran = _run_in_this_process(run, env, reservation)
    else:
        settle = _settle_s(args, machine, plan)
        total = planned_duration_s(args.program, machine.nc, settle_s=settle, json_out=args.json)
        result = run_reserved(run, logs, processes_env, reservation, quiet=args.json, total_s=total)
        timing = log_record(run.clock_log(result.logs), "TIMING") or {}
        ran = Ran(result.code, result.reason, timing, foreign_messages(result.logs.values()))
    finished, recovered = None, None
    if any(n.role == "recorder" for n in run.nodes()):
        problem, recovered = make_readable(bag)
        finish = _finish_axis if machine.axis_file else _finish
        finished = (None, problem) if problem else finish(bag, machine, args.program)
    else:
        print(f"started here: {', '.join(here)}; the recorder runs elsewhere")
    return _end(
        args, machine, plan=plan, ran=ran, finished=finished, recovered=recovered, here=here,
        bag=bag, env=env,
    )  # fmt: skip


@dataclass(frozen=True)
class Ran:
    """How the run's nodes ended: the exit code, the reason, the clock's timing record and what
    they refused as foreign."""

    code: int
    reason: str
    timing: dict
    foreign: ForeignLedger


@dataclass(frozen=True)
class Figures:
    """The mode's figures of a finished run: the JSON fields and the summary's lines."""

    values: dict
    lines: tuple[str, ...]


def _run_in_this_process(
    plan: RunPlan, env: MutableMapping[str, str], reservation: DomainReservation | None
) -> Ran:
    """Every node of the plan in this process on one executor (--single-process); the clock's
    timing is its sim node's."""
    try:
        code, nodes = run_in_this_process(plan)
    finally:
        if reservation is not None:
            reservation.release()
        preflight.end_environment(env)
    foreign = merge([n.foreign_record().as_dict() for n in nodes])
    reason = next((n.exit_message for n in nodes if n.exit_code and n.exit_message), "")
    sim = next(n for n in nodes if n.role == "sim")
    return Ran(code, reason, sim.timing_report(), foreign)


def _settle_s(args: argparse.Namespace, machine: MachineConfig, plan: NodePlan) -> float:
    """[s] simulated after the program: --settle, or an axis file's ros.settle_s."""
    if not machine.axis_file:
        return args.settle
    return load_node_set_config(plan.files[machine.simulated[0]]).settle_s


def _bag_bytes(args: argparse.Namespace, machine: MachineConfig, plan: NodePlan) -> int:
    """The bag the run will write: each simulated axis's messages over the program (or
    --max-time) and the settling time."""
    ros = load_node_set_config(plan.files[machine.simulated[0]])
    duration = 0.0
    if args.program is not None:
        duration = preflight.program_duration_s(args.program, machine.nc)
        duration += _settle_s(args, machine, plan)
    if args.max_time is not None:
        duration = min(duration, args.max_time) if duration else args.max_time
    per_axis = preflight.estimate_bag_bytes(duration, ros.exchange_period_s)
    return per_axis * len(machine.simulated)


def _end(
    args: argparse.Namespace,
    machine: MachineConfig,
    *,
    plan: NodePlan,
    ran: Ran,
    finished: tuple[Figures | None, str] | None,
    recovered: int | None,
    here: list[str],
    bag: Path,
    env: Mapping[str, str],
) -> int:
    """The run's report (RunReport): the exit code, the reason said, the outputs, the mode's
    figures; `finished`: the figures or why there are none (None: the recorder ran
    elsewhere); `recovered`: the messages kept when the bag had to be recovered."""
    rrd = bag.with_name(f"{bag.name}.rrd")
    summary, problem = finished if finished is not None else (None, "")
    if summary is not None and not machine.axis_file:
        # the machine's dashboard, written at the end (its axes streamed live as they ran);
        # an axis's recorder streamed its whole dashboard
        show_recording(getattr(args, "live_viewer", None), rrd)
    failed = ran.code != 0 or (summary is None and finished is not None)
    code = preflight.exit_status(ran.code) if ran.code else int(failed)
    reason = _with_trip_line(_named(ran.reason, plan), bag, machine, args.program)
    reason = preflight.with_disk_full(reason, bag)
    if code == 130:
        print("feed-twin run: interrupted: the figures below cover the run until the stop")
    for line in ran.foreign.lines():
        print(line)  # the run's own output names who sent what it dropped
    logs = args.out / f"{bag.name}.logs"
    for said in (reason, problem, slow_line(logs)):
        if said:
            print(f"feed-twin run: {said}", file=sys.stderr)
    preflight.remove_incomplete_rrd(rrd)
    run_timing = RunTiming.from_report(ran.timing)
    figures = {} if summary is None else summary.values
    if not machine.axis_file:
        figures = {"processes": here, **figures}
    samples = run_timing.steps if run_timing.steps is not None else figures.get("samples")
    report = RunReport(
        mode=mode_name(args, machine=not machine.axis_file),
        exit_code=code,
        reason=reason or problem,
        bag=preflight.shown_output(bag),
        rrd=preflight.shown_output(rrd, rrd=True),
        logs=str(args.out / f"{bag.name}.logs"),
        ros_domain=ros_domain(env),
        samples=samples,
        bag_recovered_messages=recovered,
        timing=run_timing,
        figures=figures,
        figure_lines=() if summary is None else summary.lines,
        foreign_messages=ran.foreign.as_dict(),
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


def _with_trip_line(reason: str, bag: Path, machine: MachineConfig, program: Path | None) -> str:
    """`reason` with the program line active at a drive fault's time added to the fault's
    line (feed_twin.nodeset.protection.describe_trip), read from the tripped axis's commands
    (an axis file's: its one axis, the reason names none)."""
    from feed_twin.io.bag import BagError, BagReader
    from feed_twin.nodeset.protection import describe_trip
    from feed_twin.ros.gcode_node import program_lines

    head, _, rest = reason.partition("\n")
    axis = head.removeprefix("axis ").partition(":")[0]
    if machine.axis_file:
        axis = machine.simulated[0]
    if "drive fault " not in head or axis not in machine.axes or not bag.exists():
        return reason
    topic = _topics(machine, axis).command
    try:
        run = {topic: BagReader(bag).columns(topic, ["header.stamp", "line"])}
    except (BagError, ValueError, OSError):
        return reason
    lines = program_lines(program) if program is not None else None
    head = describe_trip(head, run, topic, lines)
    return f"{head}\n{rest}" if rest else head


def _topics(machine: MachineConfig, axis: str) -> AxisTopics:
    """The topics of `axis`'s nodes: `/<machine>/<axis>`, an axis file's as its ros: names."""
    if machine.axis_file:
        ros = load_node_set_config(machine.source)
        return AxisTopics(machine=ros.machine, axis=ros.axis)
    return AxisTopics(machine=machine.name, axis=axis.lower())


def make_readable(bag: Path) -> tuple[str, int | None]:
    """("", messages kept or None) when the run's bag can be read (recovered first when the
    recording was cut short), else (why not, None)."""
    from feed_twin.io.bag import BagError, info, recover

    if not bag.exists():
        return "no bag was written", None
    try:
        info(bag)
    except BagError:
        try:
            kept = recover(bag).messages_recovered
        except BagError as exc:
            return f"the bag is unreadable: {exc}", None
        print(f"bag: the recording was incomplete; recovered {kept} messages")
        return "", kept
    return "", None


def _finish(bag: Path, machine: MachineConfig, program: Path | None) -> tuple[Figures | None, str]:
    """The contour error added to the (readable) bag, and the run's figures."""
    import numpy as np

    from feed_twin.gcode.geometry import programmed_path
    from feed_twin.io.bag import BagError, BagReader, add_topics
    from feed_twin.io.cdr import FlatCodec

    if program is None:
        return None, "a machine's figures need its PROGRAM"
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
    summary = record.summary()
    return Figures(summary, tuple(_figure_lines(machine, summary))), ""


def _finish_axis(
    bag: Path, machine: MachineConfig, program: Path | None
) -> tuple[Figures | None, str]:
    """An axis file's run: its dashboard and the axis's figures from the (readable) bag
    (feed_twin.nodeset.summary)."""
    from feed_twin.nodeset.summary import read_run, summarise, write_dashboard
    from feed_twin.ros.gcode_node import program_lines

    topics = _topics(machine, machine.simulated[0])
    run = read_run(bag, topics)  # only the run's messages were recorded
    rrd = bag.with_name(f"{bag.name}.rrd")
    if room := preflight.dashboard_room(bag, rrd):
        print(f"feed-twin run: {room}", file=sys.stderr)
    else:
        lines = program_lines(program) if program is not None else None
        write_dashboard(run, topics, rrd, program_lines=lines)
    try:
        summary = summarise(run, topics)
    except ValueError as exc:
        return None, str(exc)
    return Figures(summary.as_dict(), tuple(summary.format().splitlines())), ""


def _figure_lines(machine: MachineConfig, summary: dict[str, Any]) -> list[str]:
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
