"""`feed-twin run PROGRAM --config CONFIG`: the run of an axis or machine config, in every mode.

Without `--shadow` (and `--nc linuxcnc`) an axis file runs as its one-axis machine
(feed_twin.machine.config.load_run_config): its node set through feed_twin.ros.machine_run
(the G-code, controller, sim and recorder nodes of the single-axis run, in the processes
`ros.recorder_host` chooses, or this one with `--single-process`), in-process
(`--in-process`) through feed_twin.machine.run_cli, as a machine file does. Every run checks
the config, the program and the output directory in-process first (feed_twin/ros/preflight.py)
and ends with the report of every mode (feed_twin.nodeset.run_report); `--json` makes its last
line one JSON object.

`--shadow` (the axis config's shadow: section): the G-code, stand-in (the "real machine",
following the G-code node's commands; feed_twin.ros.standin_node --follow), twin and recorder
nodes, as separate processes (feed_twin.launch.axis). The runner writes the column map
`<run>_map.yaml` of the machine's topics first; the twin node writes the `.rrd` (the shadow
dashboard; `--live` streams it); the summary is the machine's (following error x_setpoint -
x_measured, peak measured current) plus the shadow figures (feed_twin.shadow.summary). With
`--nc linuxcnc` LinuxCNC runs the program headless in the stand-in's place. A machine config's
shadow node set: feed_twin.ros.machine_shadow_run. Processes are started and watched by
`launch`, which `feed-twin shadow` uses too. SIGINT/SIGTERM stop every node cleanly; the bag
is recovered if the recorder was killed.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from feed_twin.core.config import ConfigError
from feed_twin.io.live import add_live_options, linger, start_live
from feed_twin.launch.axis import AxisRunFiles, axis_plan
from feed_twin.launch.plan import RunPlan
from feed_twin.launch.request import RunRequest
from feed_twin.machine.config import is_machine_file
from feed_twin.nodeset.foreign import ForeignLedger
from feed_twin.nodeset.run_report import emit
from feed_twin.ros import preflight
from feed_twin.ros.executors import run_processes
from feed_twin.ros.launch import (
    foreign_messages,
    log_record,
    planned_duration_s,
    slow_line,
    slow_nodes,
)

if TYPE_CHECKING:
    from feed_twin.linuxcnc.summary import LinuxcncFigures
    from feed_twin.nodeset.summary import RunSummary
    from feed_twin.shadow.summary import ShadowFigures

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "config" / "axis_default.yaml"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("program", type=Path, nargs="?", help="G-code program")
    parser.add_argument(
        "--config", type=Path, default=DEFAULT_CONFIG,
        help=f"axis or machine YAML (default: {DEFAULT_CONFIG}, this checkout's)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=Path("bags"), help="output directory")
    parser.add_argument("--name", default=None, help="bag name (default: program + time)")
    parser.add_argument("--realtime", action="store_true", help="pace by the wall clock")
    parser.add_argument("--json", action="store_true", help="last line: one JSON object")
    parser.add_argument(
        "--single-process", action="store_true",
        help="every node in this one process on one executor (no DDS between processes)",
    )  # fmt: skip
    add_live_options(parser)
    parser.add_argument("--optional-stop", action="store_true", help="M1 pauses")
    parser.add_argument("--max-time", type=float, default=None, help="simulated seconds at most")
    parser.add_argument(
        "--input-timeout", type=float, default=10.0, help="silence on an input topic [s]"
    )
    parser.add_argument(
        "--startup-timeout", type=float, default=120.0,
        help="[s] for every node to come up and see its peers (default 120)",
    )  # fmt: skip
    parser.add_argument(
        "--shadow",
        action="store_true",
        help="the stand-in machine follows the program and the shadow twin runs beside it "
        "(the config's shadow: section)",
    )
    parser.add_argument(
        "--nc",
        choices=("feed_twin", "linuxcnc"),
        default="feed_twin",
        help="the NC: feed_twin's G-code node, or LinuxCNC running the program headless with "
        "its simulated servos (with --shadow; feed_twin.linuxcnc)",
    )
    parser.add_argument(
        "--domain-id",
        type=int,
        default=None,
        help="ROS domain of the run (default: ROS_DOMAIN_ID if set, else a free one reserved "
        "for the run, so runs on one host never meet)",
    )
    parser.add_argument(
        "--no-gcode",
        action="store_true",
        help="start no G-code node: the command stream comes from outside (a real NC)",
    )
    parser.add_argument(
        "--axes", default=None, help="machine config: the simulated axes, e.g. X,Z (default all)"
    )
    parser.add_argument(
        "--settle", type=float, default=0.2, help="machine config: simulated after the end [s]"
    )
    parser.add_argument(
        "--start",
        default=None,
        help="machine config: start only these of the run's processes (names such as x_sim, or "
        "roles: sim, controller, gcode, recorder), the others run on other computers",
    )
    parser.add_argument(
        "--in-process",
        action="store_true",
        help="machine config: every axis on the engine in this process instead of ROS nodes",
    )


@dataclass
class Outputs:
    bag: Path
    rrd: Path
    logs: Path
    map: Path  # --shadow: the column map of the machine's topics in the bag
    recovered: int | None = None  # messages kept when the bag had to be recovered
    # what the nodes refused as foreign (feed_twin.nodeset.foreign)
    foreign: ForeignLedger = field(default_factory=ForeignLedger)


def _outputs(args: argparse.Namespace) -> Outputs:
    name, out = args.name, args.out  # checked by preflight.run_name
    return Outputs(
        bag=out / name,
        rrd=out / f"{name}.rrd",
        logs=out / f"{name}.logs",
        map=out / f"{name}_map.yaml",
    )


def _check_inputs(args: argparse.Namespace):
    """Config sections and the whole program, before any node starts."""
    from feed_twin.gcode import validate_program

    ros, nc = preflight.check_run_config(args.config, shadow=args.shadow)
    if args.program is not None:
        validate_program(args.program, nc)
    if args.shadow:
        from feed_twin.shadow.config import load_shadow_config

        shadow = load_shadow_config(args.config)
        if abs(shadow.sample_period_s - nc.interpolation_period_s) > 1e-12:
            raise ConfigError(
                f"{args.config}: shadow.sample_period_s = {shadow.sample_period_s!r}: must equal "
                f"nc.interpolation_period_s = {nc.interpolation_period_s!r} (the twin shadows "
                "the NC's command stream)"
            )
    return ros, nc


def _write_shadow_map(args: argparse.Namespace, ros, nc, out: Outputs) -> None:
    """The column map of the machine's topics (the twin node reads it; so can `replay`)."""
    from feed_twin.analysis.twin import ModelDoc, Twin
    from feed_twin.nodeset.topics import AxisTopics
    from feed_twin.shadow.standin import write_map

    axis = next(a for a in nc.axes if a.name == nc.twin_axis)
    # LinuxCNC's HAL servo reports no effort; its rapids reach the axis velocity limit
    linuxcnc = args.nc == "linuxcnc"
    write_map(
        out.map,
        Twin.compile(ModelDoc.load(args.config)),
        AxisTopics(machine=ros.machine, axis=ros.axis).namespace,
        travel_m=axis.travel_max_m - axis.travel_min_m,
        with_effort=not linuxcnc,
        max_speed_m_s=1.5 * axis.rapid_m_s if linuxcnc else 0.5,
    )


def _plan(args: argparse.Namespace, ros, out: Outputs) -> RunPlan:
    """The shadow run's processes and their nodes (feed_twin.launch.axis)."""
    files = AxisRunFiles(bag=out.bag, rrd=out.rrd, map=out.map)
    return axis_plan(RunRequest.from_args(args), ros, files)


def _run_processes(args: argparse.Namespace, ros, nc, out: Outputs) -> tuple[int, str, dict]:
    plan = _plan(args, ros, out)
    total = planned_duration_s(args.program, nc, settle_s=ros.settle_s, json_out=args.json)
    result = run_processes(plan, out.logs, dict(os.environ), quiet=args.json, total_s=total)
    out.foreign = foreign_messages(result.logs.values())
    return result.code, result.reason, log_record(plan.clock_log(result.logs), "TIMING") or {}


def _finish_outputs(args: argparse.Namespace, ros, out: Outputs):
    """The bag made readable (recovered if the recorder was killed) and the shadow figures."""
    from feed_twin.io.bag import BagError, info, recover
    from feed_twin.nodeset.topics import AxisTopics

    if not out.bag.exists():
        return None, "no bag was written"
    try:
        info(out.bag)
    except BagError:
        try:
            out.recovered = recover(out.bag).messages_recovered
        except BagError as exc:
            return None, f"the bag is unreadable: {exc}"
        print(f"bag: the recording was incomplete; recovered {out.recovered} messages")
    return _finish_shadow(args, AxisTopics(machine=ros.machine, axis=ros.axis), out)


def _finish_shadow(args: argparse.Namespace, topics, out: Outputs):
    """The machine's run figures and the shadow figures (the twin node wrote the .rrd)."""
    from feed_twin.shadow.replay import twin_namespace
    from feed_twin.shadow.summary import summarise_shadow

    report = log_record(out.logs / "twin.log", "SHADOW") or {}
    lag = (report.get("lag_ms") or {}).get("p99")
    try:
        run, figures = summarise_shadow(
            out.bag,
            command_topic=topics.command,
            twin_namespace=twin_namespace(topics.command),
            effort_unit=report.get("effort_unit") or _effort_unit(args.config),
            lag_p99_ms=float(lag) if lag is not None else math.nan,
            config=args.config,
            column_map=out.map,
        )
    except ValueError as exc:
        return None, str(exc)
    extra = None
    if args.nc == "linuxcnc":
        from feed_twin.linuxcnc.summary import linuxcnc_figures

        report = log_record(out.logs / "linuxcnc.log", "LINUXCNC") or {}
        namespace = twin_namespace(topics.command)
        extra = linuxcnc_figures(out.bag, twin_namespace=namespace, report=report)
        _linuxcnc_dashboard(args, topics, out, extra.format())
    return _ShadowSummary(run, figures, extra), ""


def _linuxcnc_dashboard(args: argparse.Namespace, topics, out: Outputs, figures: str) -> None:
    """`<run>_linuxcnc.rrd` beside the twin's: LinuxCNC's servo samples, PID output, timing."""
    import numpy as np

    from feed_twin.io.bag import BagError
    from feed_twin.io.live import show_recording
    from feed_twin.linuxcnc.dashboard import read_servo_trace, write_linuxcnc_dashboard

    try:
        trace = read_servo_trace(out.bag, topics.servo)
    except (BagError, ValueError) as exc:
        print(f"feed-twin run: no LinuxCNC dashboard: {exc}", file=sys.stderr)
        return
    if len(trace.t_s) < 2:
        return
    rrd = out.bag.with_name(f"{out.bag.name}_linuxcnc.rrd")
    period = float(np.median(np.diff(trace.t_s)))
    write_linuxcnc_dashboard(trace, topics.axis.upper(), period, figures, rrd)
    show_recording(getattr(args, "live_viewer", None), rrd)


def _effort_unit(config: Path) -> str:
    from feed_twin.analysis.twin import ModelDoc, Twin

    return Twin.compile(ModelDoc.load(config)).effort_unit


@dataclass
class _ShadowSummary:
    run: RunSummary  # of the machine
    figures: ShadowFigures
    extra: LinuxcncFigures | None = None  # with --nc linuxcnc

    def format(self) -> str:
        text = f"{self.run.format()}\n{self.figures.format()}"
        return text if self.extra is None else f"{text}\n{self.extra.format()}"

    def as_dict(self) -> dict:
        extra = {} if self.extra is None else self.extra.as_dict()
        return {**self.run.as_dict(), **self.figures.as_dict(), **extra}


def main(args: argparse.Namespace) -> int:
    """The run in any mode; with --live, its dashboards served in a browser during the run (or
    once written, for the modes that write them at the end) and after it (feed_twin.io.live)."""
    try:
        viewer = start_live(args)
    except (ValueError, RuntimeError) as exc:
        return _early_error(args, str(exc))
    args.live_viewer = viewer
    args.live_url = None if viewer is None else viewer.grpc_url
    try:
        code = _run(args)
    except BaseException:
        if viewer is not None:
            viewer.stop()
        raise
    if code == 2 and viewer is not None:  # nothing ran: nothing to show
        viewer.stop()
        return code
    linger(viewer, args.live_linger)
    return code


def _run(args: argparse.Namespace) -> int:
    problem = _name_and_out(args)
    if problem:
        return _early_error(args, problem)
    if is_machine_file(args.config) or args.in_process:
        return _main_machine(args)  # in-process, an axis file runs as a one-axis machine
    if args.program is None and not args.no_gcode:
        print(
            "feed-twin run: a PROGRAM is needed (or --no-gcode for an external NC)", file=sys.stderr
        )
        return 2
    if not args.shadow and args.nc == "feed_twin" and args.axes is None:
        return _main_machine(args)  # an axis's node set is its one-axis machine's
    prepared = _option_problem(args) or _prepare(args)
    if isinstance(prepared, str):
        return _early_error(args, prepared)
    ros, nc, out, reservation = prepared
    try:
        code, reason, timing = _run_processes(args, ros, nc, out)
        summary, problem = _finish_outputs(args, ros, out)
    finally:
        if reservation is not None:
            reservation.release()
        preflight.end_environment(os.environ)
    code = 1 if code == 0 and summary is None else preflight.exit_status(code)
    reason = preflight.with_disk_full(reason, out.bag)
    reason = _said(args, out, code, reason, problem if summary is None else "")
    preflight.remove_incomplete_rrd(out.rrd)
    report = _report(args, out, code=code, reason=reason, summary=summary, timing=timing)
    return emit(report, json_out=args.json)


def _option_problem(args: argparse.Namespace) -> str:
    """Why the axis run's options cannot run together ("" when they can)."""
    if args.axes is not None:
        return f"--axes needs a machine config or --in-process; {args.config} is one axis"
    if args.shadow and (args.single_process or args.no_gcode):
        return (
            "--shadow runs the G-code node, the stand-in machine and the twin as separate "
            "processes: it cannot be combined with --single-process or --no-gcode"
        )
    return (_linuxcnc_precheck(args) or "") if args.nc == "linuxcnc" else ""


def _prepare(args: argparse.Namespace):
    """The checked config sections, the outputs, the run's domain and (shadow) the column map;
    or the one line why not, before any node started."""
    from feed_twin.gcode import GcodeError

    try:
        ros, nc = _check_inputs(args)
        preflight.check_output_dir(args.out, preflight.estimate_run_bytes(args, ros, nc))
    except GcodeError as exc:
        return f"G-code error, nothing was started: {exc}"
    except (ConfigError, ValueError, OSError) as exc:
        return str(exc)
    out = _outputs(args)
    try:
        reservation = preflight.run_environment(args, os.environ)
    except (ValueError, RuntimeError) as exc:
        return str(exc)
    if args.shadow:
        try:
            _write_shadow_map(args, ros, nc, out)
        except (ConfigError, ValueError, OSError) as exc:
            if reservation is not None:
                reservation.release()
            preflight.end_environment(os.environ)
            return str(exc)
    return ros, nc, out, reservation


def _said(args: argparse.Namespace, out: Outputs, code: int, reason: str, problem: str) -> str:
    """Print why the run ended as it did (interrupted, a node's reason, what kept the figures
    from the bag, slow nodes); returns the reason (for LinuxCNC, the bridge's own line for its
    fault)."""
    if code == 130:
        print("feed-twin run: interrupted: the figures below cover the run until the stop")
    if reason and args.nc == "linuxcnc":
        # the bridge's own line for a LinuxCNC fault, without the log record's prefix
        reason = (log_record(out.logs / "linuxcnc.log", "LINUXCNC") or {}).get("fault") or reason
    for said in (reason, problem):
        if said:
            print(f"feed-twin run: {said}", file=sys.stderr)
    slow = slow_line(out.logs)
    if slow:
        print(f"feed-twin run: {slow}", file=sys.stderr)
    return reason


def _main_machine(args: argparse.Namespace) -> int:
    """`feed-twin run` of a machine config: in-process, its node set or its shadow node set."""
    from feed_twin.machine.run_cli import prepare_machine, run_machine

    if args.nc == "linuxcnc" and (args.in_process or not args.shadow):
        return _early_error(
            args,
            "--nc linuxcnc runs the program on LinuxCNC with the machine's twins beside it: "
            "add --shadow (without --in-process)",
        )
    if args.in_process:
        return run_machine(args)
    machine = prepare_machine(args)
    if isinstance(machine, int):
        return machine
    if args.shadow:
        from feed_twin.ros.machine_shadow_run import run_machine_shadow

        return run_machine_shadow(args, machine)
    from feed_twin.ros.machine_run import run_machine_nodes

    return run_machine_nodes(args, machine)


def _name_and_out(args: argparse.Namespace) -> str:
    """Why the run's name or (machine config) --out cannot be used ("": they can); sets
    args.name to the run's name (preflight.run_name) for every mode."""
    stem = args.program.stem if args.program is not None else "external"
    try:
        args.name = preflight.run_name(args.out, args.name, stem, time.strftime("%Y%m%d_%H%M%S"))
        if is_machine_file(args.config):
            # the machine's bag is sized by its axes' nodes; here: that --out takes files
            preflight.check_output_dir(args.out, 0)
    except ConfigError as exc:
        return str(exc)
    return ""


def _report(args: argparse.Namespace, out: Outputs, *, code: int, reason: str, summary, timing):
    """The run's end as `RunReport`: outputs, domain, timing and the mode's figures."""
    from feed_twin.nodeset.run_report import RunReport, RunTiming, mode_name, ros_domain

    if args.nc == "linuxcnc" and not timing:
        timing = _linuxcnc_timing(out)
    run_timing = RunTiming.from_report(timing)
    figures = summary.as_dict() if summary is not None else {}
    samples = run_timing.steps if run_timing.steps is not None else figures.get("samples")
    column_map = out.map if args.shadow and out.map.exists() else None
    return RunReport(
        mode=mode_name(args, machine=False),
        exit_code=code,
        reason=reason,
        bag=preflight.shown_output(out.bag),
        rrd=preflight.shown_output(out.rrd, rrd=True),
        column_map=str(column_map) if column_map is not None else None,
        logs=str(out.logs),
        ros_domain=ros_domain(os.environ),
        samples=samples,
        bag_recovered_messages=out.recovered,
        timing=run_timing,
        figures=figures,
        figure_lines=tuple(summary.format().splitlines()) if summary is not None else (),
        foreign_messages=out.foreign.as_dict(),
        slow_nodes=slow_nodes(out.logs),
    )


def _linuxcnc_timing(out: Outputs) -> dict:
    """Beside LinuxCNC the run is paced by LinuxCNC's servo thread: its lateness is how late
    the twin shadows it, servo tick -> the twin's output back at the bridge (LINUXCNC record)."""
    report = log_record(out.logs / "linuxcnc.log", "LINUXCNC") or {}
    if not report.get("twin_output_latency_count"):
        return {}
    return {
        "steps": report.get("samples_published"),
        "sim_time_s": report.get("program_time_s"),
        "wall_time_s": report.get("wall_s"),
        "lateness_p50_ms": report.get("twin_output_latency_p50_ms"),
        "lateness_p99_ms": report.get("twin_output_latency_p99_ms"),
        "lateness_max_ms": report.get("twin_output_latency_max_ms"),
    }


def _linuxcnc_precheck(args: argparse.Namespace) -> str | None:
    """Why `--nc linuxcnc` cannot run: options, LinuxCNC missing, one interpreter only."""
    if not args.shadow or args.program is None:
        return "--nc linuxcnc runs a PROGRAM on LinuxCNC with the twin beside it: add --shadow"
    from feed_twin.linuxcnc.host import LinuxcncError, check_installed
    from feed_twin.linuxcnc.summary import sides_disagree

    try:
        check_installed()
        return sides_disagree(args.program, args.config)
    except (LinuxcncError, ConfigError, ValueError, OSError) as exc:
        return str(exc)


def _early_error(args: argparse.Namespace, message: str) -> int:
    """A run refused before anything started: the reason, then the report of every mode."""
    from feed_twin.nodeset.run_report import early_error_report, emit, mode_name

    print(f"feed-twin run: {message}", file=sys.stderr)
    machine = is_machine_file(args.config)
    return emit(early_error_report(mode_name(args, machine=machine), message), json_out=args.json)
