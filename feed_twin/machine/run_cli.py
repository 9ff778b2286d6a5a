"""`feed-twin run PROGRAM --config MACHINE.yaml [--axes X,Z]`: the machine twin.

By default the machine runs as its ROS node set (feed_twin.ros.machine_run: a sim and a
controller node per axis, each in its own process; with `--shadow`
feed_twin.ros.machine_shadow_run: a stand-in and a twin node per axis). With `--in-process` a
machine config (feed_twin.machine.config), or an axis config as a one-axis machine
(`load_run_config`), runs every simulated axis of the machine on the engine in this process
(feed_twin.machine.simulate), in lockstep on the NC's sample grid; the program and the config
are checked first and a bad one stops the run with one line before anything moves. Outputs:
- the bag `<out>/<name>` (rosbag2 MCAP): per NC axis `/<machine>/<axis>/command` (AxisCommand;
  a rotary axis's position in rad), per simulated axis `/<machine>/<axis>/state` (AxisState from
  the engine's signals: setpoint, table truth, motor, currents, voltages, forces), and the
  contour error `/<machine>/contour_error` and its along-path lag `/<machine>/contour_lag`
  (std_msgs/Float64 [m], log time = simulation time);
- the `.rrd` dashboard (feed_twin.machine.dashboard): XY and XZ paths coloured by contour
  error beside per-axis following error;
- the summary, and with `--json` one JSON object last (contour_error_max_m, contour_error_rms_m,
  following_error_max_m per axis, the engine's realtime factor, the paths).
`--in-process --shadow` adds the shadow twin of every simulated axis beside its stand-in
(feed_twin.machine.shadow, over the program's samples): residuals and health per axis in the
summary and under "shadow" in the JSON line. In-process, the node-set options (--realtime,
--single-process, --no-gcode) are refused; --live shows the dashboard once written.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.io import msg_types
from feed_twin.io.bag import BagWriter
from feed_twin.io.cdr import FlatCodec
from feed_twin.machine.config import MachineConfig, is_machine_file, load_run_config
from feed_twin.machine.simulate import MachineRun, simulate_machine
from feed_twin.nodeset.config import StateSignals
from feed_twin.nodeset.run_report import (
    RunReport,
    RunTiming,
    early_error_report,
    emit,
    mode_name,
    shown,
)
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.sim.engine import DivergenceError

NODE_SET_OPTIONS = ("realtime", "single_process", "no_gcode")


def _state_fields(
    signals: dict[str, np.ndarray], command: np.ndarray, names: StateSignals
) -> dict[str, np.ndarray]:
    """AxisState fields from the engine's signals (NaN where the plant has no such signal)."""
    nan = np.full(len(command), np.nan)

    def get(name: str | None) -> np.ndarray:
        if not name:
            return nan
        sign = -1.0 if name.startswith("-") else 1.0
        values = signals.get(name.lstrip("-"))
        return nan if values is None else sign * values

    u_dc, i_dc = get(names.u_dc), get(names.i_dc)
    torque, omega = get(names.torque_em), get(names.motor_velocity)
    return {
        "position_setpoint": get("out.pos_ref_m"),
        "table_position": get(names.table_position),
        "table_velocity": get(names.table_velocity),
        "table_acceleration": get("table.a"),
        "following_error": get("out.following_error_m"),
        "motor_angle": get(names.motor_angle),
        "motor_velocity": omega,
        "i_d": get(names.i_d),
        "i_q": get(names.i_q),
        "u_d": get(names.u_d),
        "u_q": get(names.u_q),
        "u_dc": u_dc,
        "torque_em": torque,
        "friction_force": get(names.friction_force),
        "screw_force": get(names.screw_force),
        "electrical_power": u_dc * i_dc,
        "mechanical_power": torque * omega,
    }


def write_machine_bag(run: MachineRun, machine: MachineConfig, path: Path) -> Path:
    """The run as a rosbag2 MCAP bag (module docstring); returns the bag's info."""
    stamps = np.round(run.t_s * NS_PER_S).astype(np.int64)
    command = FlatCodec(msg_types.AXIS_COMMAND)
    state = FlatCodec(msg_types.AXIS_STATE)
    scalar = FlatCodec(msg_types.FLOAT64)
    root = f"/{machine.name}"
    with BagWriter(path) as bag:
        for i, axis in enumerate(run.axes):
            topic = AxisTopics(machine=machine.name, axis=axis.lower()).command
            bag.add_topic(topic, msg_types.AXIS_COMMAND)
            for k, t_ns in enumerate(stamps):
                values = {
                    "header.stamp.sec": int(t_ns // NS_PER_S),
                    "header.stamp.nanosec": int(t_ns % NS_PER_S),
                    "header.frame_id": "",
                    "axis": axis,
                    "position": float(run.command[k, i]),
                    "velocity": float(run.command_vel[k, i]),
                    "acceleration": float(run.command_acc[k, i]),
                    "line": int(run.line[k]),
                }
                bag.write(topic, command.encode_map(values), log_time_ns=int(t_ns))
        for axis in run.simulated:
            topic = AxisTopics(machine=machine.name, axis=axis.lower()).state
            bag.add_topic(topic, msg_types.AXIS_STATE)
            fields = _state_fields(
                run.signals[axis], run.command[:, run.axes.index(axis)], run.state_signals[axis]
            )
            for k, t_ns in enumerate(stamps):
                values: dict[str, float | int | str] = {n: float(c[k]) for n, c in fields.items()}
                values.update({
                    "header.stamp.sec": int(t_ns // NS_PER_S),
                    "header.stamp.nanosec": int(t_ns % NS_PER_S),
                    "header.frame_id": "",
                    "axis": axis,
                })  # fmt: skip
                bag.write(topic, state.encode_map(values), log_time_ns=int(t_ns))
        for name, column in (("contour_error", run.contour.normal_m),
                             ("contour_lag", run.contour.lag_m)):  # fmt: skip
            topic = f"{root}/{name}"
            bag.add_topic(topic, msg_types.FLOAT64)
            for k, t_ns in enumerate(stamps):
                bag.write(
                    topic, scalar.encode_map({"data": float(column[k])}), log_time_ns=int(t_ns)
                )
    return path


def prepare_machine(args: argparse.Namespace) -> MachineConfig | int:
    """The machine of a `feed-twin run` (its --axes selection), its program checked on the
    machine's NC; or the exit code after a one-line error."""
    from feed_twin.gcode import GcodeError
    from feed_twin.gcode.planner import validate_program
    from feed_twin.nodeset.reach import check_reachable

    refused = [f"--{o.replace('_', '-')}" for o in NODE_SET_OPTIONS if getattr(args, o, False)]
    if refused and args.in_process:
        return _error(
            args,
            f"{', '.join(refused)}: not available for a machine config run in-process "
            f"({args.config}; without --in-process it runs as ROS nodes)",
        )
    external = getattr(args, "no_gcode", False) and not args.in_process  # an axis file's
    if args.program is None and not external:
        return _error(args, "a PROGRAM is needed")
    try:
        machine = load_run_config(args.config)
        if args.axes:
            machine = machine.select(args.axes.split(","))
        if args.program is not None:
            validate_program(args.program, machine.nc)
        for name, axis in machine.axes.items():  # the node set checks each axis's file so
            check_reachable(
                axis,
                dataclasses.replace(machine.nc, twin_axis=name),
                None,
                source=f"{machine.source}: axis {name}",
            )
    except GcodeError as exc:
        return _error(args, f"G-code error, nothing was started: {exc}")
    except (ConfigError, ValueError, OSError) as exc:
        return _error(args, str(exc))
    return machine


def run_machine(args: argparse.Namespace) -> int:
    """The in-process `feed-twin run` of a machine config (module docstring)."""
    from feed_twin.gcode.geometry import programmed_path
    from feed_twin.io.live import show_recording
    from feed_twin.machine.dashboard import write_machine_dashboard

    machine = prepare_machine(args)
    if isinstance(machine, int):
        return machine
    name = args.name  # feed_twin.ros.preflight.run_name, before anything started
    args.out.mkdir(parents=True, exist_ok=True)
    bag_path, rrd_path = args.out / name, args.out / f"{name}.rrd"
    try:
        run = _simulate(args, machine)
    except DivergenceError as exc:
        return _error(args, f"the machine's simulation failed: {exc}")
    write_machine_bag(run, machine, bag_path)
    write_machine_dashboard(run, programmed_path(args.program, machine.nc), rrd_path)
    show_recording(getattr(args, "live_viewer", None), rrd_path)
    shadow = _shadow(args, machine) if args.shadow else None
    if isinstance(shadow, str):
        return _error(args, shadow)
    return emit(_report(args, machine, run, shadow, bag_path, rrd_path), json_out=args.json)


def _simulate(args: argparse.Namespace, machine: MachineConfig) -> MachineRun:
    """The machine's run, with its progress on a terminal (feed_twin.io.progress): the
    compilation of every axis's kernels named until the first samples are stepped."""
    from feed_twin.gcode.planner import plan_program
    from feed_twin.io.progress import Progress, wanted

    enabled = wanted(json_out=args.json)
    total = plan_program(args.program, machine.nc).t_s[-1] + args.settle if enabled else None
    bar = Progress(total_s=total, enabled=enabled)
    bar.stage("compiling every axis's kernels (numba; cached after the first run)")

    def advanced(sim_s: float) -> None:
        bar.stage("simulating")
        bar.update(sim_s)

    try:
        return simulate_machine(machine, args.program, settle_s=args.settle, on_progress=advanced)
    finally:
        bar.close()


def _report(
    args: argparse.Namespace,
    machine: MachineConfig,
    run: MachineRun,
    shadow: dict | None,
    bag: Path,
    rrd: Path,
) -> RunReport:
    """The in-process run's end: the machine's figures above the fields of every mode."""
    summary = run.summary()
    simulated = summary["simulated_s"]
    wall = run.engine_wall_s if run.engine_wall_s > 0 else None
    timing = RunTiming(
        steps=len(run.t_s),
        sim_time_s=simulated,
        wall_time_s=wall,
        realtime_factor=simulated / wall if wall else None,
    )
    commands = ", ".join(a for a in run.axes if a not in run.simulated) or "none"
    lines = [
        f"machine {machine.name}: {len(run.t_s)} samples ({simulated:.3f} s), axes "
        f"{', '.join(run.simulated)} simulated, {commands} as commands (engine: all axes, one "
        "thread)",
        *machine_figure_lines(summary),
    ]
    figures: dict = {**summary}
    if shadow is not None:
        from feed_twin.machine.shadow import format_axis_figures

        lines += [format_axis_figures(axis, f) for axis, f in shadow.items()]
        figures["shadow"] = shadow
    return RunReport(
        mode=mode_name(args, machine=not machine.axis_file),
        exit_code=0,
        bag=str(bag),
        rrd=str(rrd),
        uses_ros=False,
        samples=len(run.t_s),
        timing=timing,
        figures=figures,
        figure_lines=tuple(lines),
    )


def machine_figure_lines(summary: dict) -> list[str]:
    """The contour and following-error lines of a machine run's summary (`MachineRun.summary`)."""
    fe = ", ".join(
        f"{a} {shown(v, 'um', scale=1e6, digits=2)}"
        for a, v in summary["following_error_max_m"].items()
    )
    where = (
        f"t = {shown(summary.get('contour_error_max_t_s'), 's')} "
        f"(line {summary.get('contour_error_max_line', 'unknown')})"
    )
    return [
        f"contour error: max {shown(summary['contour_error_max_m'], 'um', scale=1e6)} at "
        f"{where}, RMS {shown(summary['contour_error_rms_m'], 'um', scale=1e6)}",
        f"following error max: {fe}",
    ]


def _shadow(args: argparse.Namespace, machine: MachineConfig) -> dict | str:
    """Every axis's shadow twin beside its stand-in (feed_twin.machine.shadow): the per-axis
    figures, printed; or the reason it cannot run."""
    from feed_twin.machine.shadow import shadow_machine

    try:
        result = shadow_machine(machine, args.program)
    except (ConfigError, ValueError) as exc:
        return f"--shadow: {exc}"
    return {axis.lower(): r.summary() for axis, r in result.items()}


def _error(args: argparse.Namespace, message: str) -> int:
    print(f"feed-twin run: {message}", file=sys.stderr)
    report = early_error_report(mode_name(args, machine=is_machine_file(args.config)), message)
    return emit(report, json_out=getattr(args, "json", False))
