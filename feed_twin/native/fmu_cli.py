"""`feed-twin fmu`: export an axis configuration as an FMI 2.0 co-simulation FMU."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from feed_twin.native.build import CompilerMissingError
from feed_twin.sim.config import load_axis_config


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="axis YAML (plant, engine, controller)")
    parser.add_argument("--out", required=True, help="FMU file to write, e.g. axis.fmu")


def main(args: argparse.Namespace) -> int:
    from feed_twin.native.fmu import build_fmu

    out = Path(args.out)
    if out.suffix != ".fmu":
        print(f"feed-twin fmu: --out {args.out}: must end in .fmu", file=sys.stderr)
        return 2
    try:
        axis = load_axis_config(args.config)
        build_fmu(axis, out)
    except (ValueError, CompilerMissingError, RuntimeError) as exc:
        # a compiler's message spans lines (ld's "No space left on device" among them)
        said = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f"feed-twin fmu: {said}", file=sys.stderr)
        return 2
    print(f"{out}: FMI 2.0 co-simulation FMU of {args.config} ({out.stat().st_size} bytes)")
    return 0
