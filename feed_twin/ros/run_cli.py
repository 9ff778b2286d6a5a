"""`feed-twin run PROGRAM --config CONFIG`: the run of an axis or machine config, in every mode.

Every config runs as a machine (feed_twin.machine.config.load_run_config: an axis file is its
one-axis machine) on one of three paths, chosen by the options:

- `--in-process`: the engines of every axis in this process (feed_twin.machine.run_cli);
- the node set: feed_twin.ros.machine_run (an axis file's nodes are the single-axis run's:
  the G-code, controller, sim and recorder nodes in the processes `ros.recorder_host` chooses,
  or this one with `--single-process`);
- `--shadow` (and `--nc linuxcnc`: LinuxCNC runs the program headless in the stand-ins'
  place): feed_twin.ros.machine_shadow_run, per axis a stand-in (the "real machine") and a
  shadow twin beside the G-code node and the recorder (an axis file's as the single-axis run
  had them, feed_twin.ros.axis_shadow: its column map `<run>_map.yaml`, its `.rrd`, its
  figures).

Every run checks the config, the program and the output directory in-process first
(feed_twin/ros/preflight.py) and ends with the report of every mode
(feed_twin.nodeset.run_report); `--json` makes its last line one JSON object. Processes are
started and watched by feed_twin.ros.launch, which `feed-twin shadow` uses too. SIGINT/SIGTERM
stop every node cleanly; the bag is recovered if the recorder was killed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from feed_twin.core.config import ConfigError
from feed_twin.io.live import add_live_options, linger, start_live
from feed_twin.machine.config import is_machine_file
from feed_twin.ros import axis_shadow, preflight

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
    if not is_machine_file(args.config) and not args.in_process:
        if args.program is None and not args.no_gcode:
            print(
                "feed-twin run: a PROGRAM is needed (or --no-gcode for an external NC)",
                file=sys.stderr,
            )
            return 2
        problem = _axis_option_problem(args)
        if problem:
            return _early_error(args, problem)
    return _main_machine(args)  # an axis file runs as its one-axis machine


def _axis_option_problem(args: argparse.Namespace) -> str:
    """Why an axis file's node-set run cannot run as asked ("" when it can), said before its
    one-axis machine is loaded: LinuxCNC's verdict on the program comes before feed_twin's."""
    if args.axes is not None:
        return f"--axes needs a machine config or --in-process; {args.config} is one axis"
    refused = axis_shadow.refused_options(args) if args.shadow else ""
    if refused or args.nc != "linuxcnc":
        return refused
    return axis_shadow.linuxcnc_precheck(args)


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
    if args.shadow:  # and --nc linuxcnc
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


def _early_error(args: argparse.Namespace, message: str) -> int:
    """A run refused before anything started: the reason, then the report of every mode."""
    from feed_twin.nodeset.run_report import early_error_report, emit, mode_name

    print(f"feed-twin run: {message}", file=sys.stderr)
    machine = is_machine_file(args.config)
    return emit(early_error_report(mode_name(args, machine=machine), message), json_out=args.json)
