"""The `feed-twin` command line.

Each subcommand lives in the module that owns its capability and exposes two functions:
`configure(parser)` adds its arguments, `main(args) -> int` runs it. Modules are imported only
when their subcommand runs, so `feed-twin --help` stays fast and a broken optional module never
hides the others.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from dataclasses import dataclass

EXIT_BROKEN_PIPE = 141  # what a shell reports for a process ended by SIGPIPE (128 + 13)


@dataclass(frozen=True, kw_only=True)
class Subcommand:
    name: str
    module: str  # dotted path of the module with configure(parser) and main(args)
    help: str
    example: str  # one command line, shown at the end of the subcommand's --help


SUBCOMMANDS: tuple[Subcommand, ...] = (
    Subcommand(
        name="diagnose",
        module="feed_twin.analysis.cli",
        help="find where twin and machine disagree, name and fit the missing effects",
        example="feed-twin diagnose ../shared/data/emps/DATA_EMPS.csv "
        "--config config/emps_nominal.yaml --map config/emps_map.yaml --out out/emps",
    ),
    Subcommand(
        name="simulate",
        module="feed_twin.analysis.simulate_cli",
        help="run a model against a measured run's command; write measured and sim_ columns",
        example="feed-twin simulate --config config/emps_nominal.yaml "
        "--measured ../shared/data/emps/DATA_EMPS.csv --map config/emps_map.yaml "
        "--out out/emps_sim.csv",
    ),
    Subcommand(
        name="info",
        module="feed_twin.info_cli",
        help="show versions and what is installed",
        example="feed-twin info",
    ),
    Subcommand(
        name="model",
        module="feed_twin.sim.model_cli",
        help="show the assembled plant of an axis config and its natural frequencies",
        example="feed-twin model --config config/axis_default.yaml",
    ),
    Subcommand(
        name="tune",
        module="feed_twin.control.tune_cli",
        help="controller gains from plant parameters and margins of the configured loops",
        example="feed-twin tune --config config/axis_default.yaml",
    ),
    Subcommand(
        name="bag",
        module="feed_twin.io.bag_cli",
        help="inspect or recover a recorded bag",
        example="feed-twin bag info bags/sample_20260101_120000",
    ),
    Subcommand(
        name="run",
        module="feed_twin.ros.run_cli",
        help="run a G-code program through the ROS 2 node set, record it and summarise it",
        example="feed-twin run tests/fixtures/gcode/sample.ngc --shadow",
    ),
    Subcommand(
        name="plan",
        module="feed_twin.gcode.cli",
        help="plan a G-code program into sampled setpoints (CSV) and print a summary",
        example="feed-twin plan tests/fixtures/gcode/sample.ngc --config config/axis_default.yaml",
    ),
    Subcommand(
        name="replay",
        module="feed_twin.shadow.replay_cli",
        help="run the shadow twin against a recorded bag; write a comparison bag, .rrd, report",
        example="feed-twin replay bags/sample_20260101_120000 --config config/axis_default.yaml "
        "--out out/replay",
    ),
    Subcommand(
        name="shadow",
        module="feed_twin.ros.shadow_cli",
        help="run the shadow twin node beside the stand-in machine node; report lag and health",
        example="feed-twin shadow --config config/emps.yaml --duration 20 --raise-friction-at 10",
    ),
    Subcommand(
        name="fmu",
        module="feed_twin.native.fmu_cli",
        help="export an axis config as an FMI 2.0 co-simulation FMU (C kernel inside)",
        example="feed-twin fmu --config config/axis_default.yaml --out axis.fmu",
    ),
    Subcommand(
        name="hal",
        module="feed_twin.native.hal_cli",
        help="build the axis twin as a LinuxCNC realtime HAL component (halcompile)",
        example="feed-twin hal --config config/axis_default.yaml --out out/hal --compile",
    ),
    Subcommand(
        name="msgs-check",
        module="feed_twin.ros.msgcheck",
        help="round-trip every message type over DDS and check every field",
        example="feed-twin msgs-check",
    ),
)


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (argparse prints its usage first, 5 lines
    for `run`), exit status 2 as argparse's."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _top_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="feed-twin",
        description="Digital twin of a CNC ball-screw feed axis on ROS 2.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for cmd in SUBCOMMANDS:
        sub.add_parser(cmd.name, help=cmd.help, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    if not argv or argv[0] in ("-h", "--help"):
        top.print_help()
        return 0 if argv else 2
    by_name = {cmd.name: cmd for cmd in SUBCOMMANDS}
    cmd = by_name.get(argv[0])
    if cmd is None:
        top.error(f"unknown command {argv[0]!r}; choose from {', '.join(by_name)}")
    module = importlib.import_module(cmd.module)
    parser = OneLineParser(
        prog=f"feed-twin {cmd.name}",
        description=cmd.help,
        epilog=f"example:\n  {cmd.example}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    module.configure(parser)
    args = parser.parse_args(argv[1:])
    try:
        return int(module.main(args) or 0)
    except BrokenPipeError:
        # The reader went away (`feed-twin plan ... | head`): nothing more to say to it. Point
        # stdout at /dev/null so that the interpreter's final flush cannot fail again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        print(f"feed-twin {cmd.name}: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        # Bad input (ConfigError, GcodeError, BagError are ValueErrors) or a file that cannot
        # be read or written: one line naming it, never a traceback.
        print(f"feed-twin {cmd.name}: {one_line(exc)}", file=sys.stderr)
        return 2


def one_line(exc: BaseException) -> str:
    """An exception as one line: its message's first line, or its type for an empty one."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
