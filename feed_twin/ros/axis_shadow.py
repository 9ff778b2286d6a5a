"""An axis file's shadow run as its one-axis machine (`feed-twin run PROGRAM [--config AXIS.yaml]
--shadow [--nc linuxcnc]`): what it checks before the machine shadow's runner
(feed_twin.ros.machine_shadow_run) plans and runs its nodes, and the figures it ends with.

The nodes, their processes and arguments are the machine shadow's plan of a one-axis machine
(feed_twin.machine.shadow_nodes.ShadowPlan.axis_file). What stays the axis's own is data of
its report: its words for refused options, its inputs checked as the axis file the nodes read
(`check_inputs`: sections, the shadow's sample period, room in --out), and its figures
(`finish`): the machine's run figures (following error x_setpoint - x_measured, peak measured
current; feed_twin.shadow.summary) and the shadow figures with the twin's output lag (its
`SHADOW` record); with LinuxCNC its figures and servo dashboard `<run>_linuxcnc.rrd`
(feed_twin.linuxcnc.summary, .dashboard), and the run's timing from the bridge's record.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from feed_twin.core.config import ConfigError
from feed_twin.machine.shadow_nodes import ShadowPlan, check_shadow_period
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.ros import preflight
from feed_twin.ros.launch import log_record

if TYPE_CHECKING:
    from feed_twin.linuxcnc.summary import LinuxcncFigures
    from feed_twin.nodeset.summary import RunSummary
    from feed_twin.shadow.summary import ShadowFigures


def refused_options(args: argparse.Namespace) -> str:
    """Why the axis's shadow run's options cannot run together ("" when they can)."""
    if args.single_process or args.no_gcode:
        return (
            "--shadow runs the G-code node, the stand-in machine and the twin as separate "
            "processes: it cannot be combined with --single-process or --no-gcode"
        )
    if args.start is not None:
        return "--start: not available for an axis's shadow node set (it starts every node here)"
    return ""


def linuxcnc_precheck(args: argparse.Namespace) -> str:
    """Why `--nc linuxcnc` cannot run on the axis file ("" when it can): options, LinuxCNC
    missing, a program only one of the two interpreters accepts (said before feed_twin's
    interpreter alone would reject it)."""
    if not args.shadow or args.program is None or args.in_process:
        return "--nc linuxcnc runs a PROGRAM on LinuxCNC with the twin beside it: add --shadow"
    from feed_twin.linuxcnc.host import LinuxcncError, check_installed
    from feed_twin.linuxcnc.summary import sides_disagree

    try:
        check_installed()
        return sides_disagree(args.program, args.config) or ""
    except (LinuxcncError, ConfigError, ValueError, OSError) as exc:
        return str(exc)


def check_inputs(args: argparse.Namespace) -> None:
    """The axis file as its nodes read it, with its shadow: section, and room in --out for the
    bag (ConfigError, ValueError or OSError, one line; nothing written)."""
    from feed_twin.shadow.config import load_shadow_config

    ros, nc = preflight.check_run_config(args.config, shadow=True)
    shadow = load_shadow_config(args.config)
    check_shadow_period(args.config, shadow.sample_period_s, nc.interpolation_period_s)
    preflight.check_output_dir(args.out, preflight.estimate_run_bytes(args, ros, nc))


def column_map(plan: ShadowPlan) -> Path:
    (axis,) = plan.axes
    return plan.maps[axis]


def topics(plan: ShadowPlan) -> AxisTopics:
    return AxisTopics(machine=plan.machine, axis=plan.ros_axis)


def finish(
    args: argparse.Namespace, plan: ShadowPlan, bag: Path, logs: Path
) -> tuple[AxisShadowSummary | None, str]:
    """The machine's run figures and the shadow figures from the (readable) bag (the twin node
    wrote the .rrd); with LinuxCNC its figures and dashboard too."""
    from feed_twin.shadow.summary import summarise_shadow

    names = topics(plan)
    report = log_record(logs / "twin.log", "SHADOW") or {}
    lag = (report.get("lag_ms") or {}).get("p99")
    try:
        run, figures = summarise_shadow(
            bag,
            command_topic=names.command,
            twin_namespace=f"{names.namespace}/twin",
            effort_unit=report.get("effort_unit") or plan.effort_units[plan.axes[0]],
            lag_p99_ms=float(lag) if lag is not None else math.nan,
            config=args.config,
            column_map=column_map(plan),
        )
    except ValueError as exc:
        return None, str(exc)
    extra = None
    if plan.linuxcnc:
        from feed_twin.linuxcnc.summary import linuxcnc_figures

        report = log_record(logs / "linuxcnc.log", "LINUXCNC") or {}
        namespace = f"{names.namespace}/twin"
        extra = linuxcnc_figures(bag, twin_namespace=namespace, report=report)
        _linuxcnc_dashboard(args, names, bag, extra.format())
    return AxisShadowSummary(run, figures, extra), ""


def _linuxcnc_dashboard(args: argparse.Namespace, names: AxisTopics, bag: Path, text: str) -> None:
    """`<run>_linuxcnc.rrd` beside the twin's: LinuxCNC's servo samples, PID output, timing."""
    import numpy as np

    from feed_twin.io.bag import BagError
    from feed_twin.io.live import show_recording
    from feed_twin.linuxcnc.dashboard import read_servo_trace, write_linuxcnc_dashboard

    try:
        trace = read_servo_trace(bag, names.servo)
    except (BagError, ValueError) as exc:
        print(f"feed-twin run: no LinuxCNC dashboard: {exc}", file=sys.stderr)
        return
    if len(trace.t_s) < 2:
        return
    rrd = bag.with_name(f"{bag.name}_linuxcnc.rrd")
    period = float(np.median(np.diff(trace.t_s)))
    write_linuxcnc_dashboard(trace, names.axis.upper(), period, text, rrd)
    show_recording(getattr(args, "live_viewer", None), rrd)


@dataclass
class AxisShadowSummary:
    run: RunSummary  # of the machine
    figures: ShadowFigures
    extra: LinuxcncFigures | None = None  # with --nc linuxcnc

    def format(self) -> str:
        text = f"{self.run.format()}\n{self.figures.format()}"
        return text if self.extra is None else f"{text}\n{self.extra.format()}"

    def as_dict(self) -> dict:
        extra = {} if self.extra is None else self.extra.as_dict()
        return {**self.run.as_dict(), **self.figures.as_dict(), **extra}


def linuxcnc_timing(bridge_said: dict) -> dict:
    """Beside LinuxCNC the run is paced by LinuxCNC's servo thread: its lateness is how late
    the twin shadows it, servo tick -> the twin's output back at the bridge (the bridge's
    LINUXCNC record `bridge_said`)."""
    if not bridge_said.get("twin_output_latency_count"):
        return {}
    return {
        "steps": bridge_said.get("samples_published"),
        "sim_time_s": bridge_said.get("program_time_s"),
        "wall_time_s": bridge_said.get("wall_s"),
        "lateness_p50_ms": bridge_said.get("twin_output_latency_p50_ms"),
        "lateness_p99_ms": bridge_said.get("twin_output_latency_p99_ms"),
        "lateness_max_ms": bridge_said.get("twin_output_latency_max_ms"),
    }
