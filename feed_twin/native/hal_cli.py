"""`feed-twin hal`: the axis twin as a LinuxCNC realtime HAL component (halcompile)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from feed_twin.sim.config import load_axis_config


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="axis YAML (plant, engine, controller)")
    parser.add_argument("--out", required=True, help="directory for feed_twin_axis.comp")
    parser.add_argument(
        "--servo-period", type=float, default=1e-3, help="LinuxCNC's servo period [s] (1e-3)"
    )
    parser.add_argument(
        "--mode",
        choices=("position", "velocity", "torque"),
        default=None,
        help="CiA 402 boundary of the pins (default: the config's controller.mode)",
    )
    parser.add_argument(
        "--module", default="feed_twin_axis", help="HAL module name (default feed_twin_axis)"
    )
    parser.add_argument(
        "--install",
        action="store_true",
        help="halcompile --install (root): into /usr/lib/linuxcnc/modules for loadrt",
    )
    parser.add_argument(
        "--compile", action="store_true", help="halcompile --compile: build the .so in --out"
    )


def main(args: argparse.Namespace) -> int:
    from feed_twin.native.hal import HalcompileMissingError, halcompile, write_comp

    try:
        axis = load_axis_config(args.config)
        comp = write_comp(
            axis, Path(args.out), args.servo_period, mode=args.mode, module=args.module
        )
        print(f"{comp}: HAL component of {args.config}, servo period {args.servo_period:g} s")
        if args.install or args.compile:
            module = halcompile(comp, install=args.install)
            where = "installed into /usr/lib/linuxcnc/modules" if args.install else "built"
            print(f"{module}: {where}")
    except (ValueError, HalcompileMissingError, RuntimeError) as exc:
        print(f"feed-twin hal: {exc}", file=sys.stderr)
        return 2
    return 0
