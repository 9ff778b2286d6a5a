"""`feed-twin plan`: G-code program -> sampled setpoints (CSV) and a summary.

The CSV has `t_s`, then for each axis `<x>_m, v<x>_m_s, a<x>_m_s2` (lower-case axis name),
then `line`. The program is validated before anything is written; the trajectory is written
chunk by chunk, so long programs run in bounded memory.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.gcode.config import ROTARY_AXIS_NAMES, load_nc_config
from feed_twin.gcode.errors import GcodeError
from feed_twin.gcode.planner import plan_program_stream


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("program", type=Path, help="G-code file")
    parser.add_argument(
        "--config", type=Path, required=True, help="YAML file with an 'nc:' section"
    )
    parser.add_argument("--out", type=Path, help="CSV file for the sampled trajectory")


def csv_header(axes: tuple[str, ...]) -> list[str]:
    columns = ["t_s"]
    for name in axes:
        a = name.lower()
        unit = "rad" if name in ROTARY_AXIS_NAMES else "m"
        columns += [f"{a}_{unit}", f"v{a}_{unit}_s", f"a{a}_{unit}_s2"]
    return columns + ["line"]


def main(args: argparse.Namespace) -> int:
    try:
        config = load_nc_config(args.config)
        chunks = plan_program_stream(args.program, config)
    except (ConfigError, GcodeError) as exc:
        print(f"feed-twin plan: {exc}", file=sys.stderr)
        return 2
    axes = config.axis_names
    n_axes = len(axes)
    peak_v = np.zeros(n_axes)
    peak_a = np.zeros(n_axes)
    path_length = 0.0
    last_pos = None
    t_end = 0.0
    n_samples = 0
    n_events = 0
    handle = args.out.open("w", encoding="utf-8") if args.out is not None else None
    try:
        if handle is not None:
            handle.write(",".join(csv_header(axes)) + "\n")
        for chunk in chunks:
            if len(chunk) == 0:
                n_events += len(chunk.events)
                continue
            peak_v = np.maximum(peak_v, np.abs(chunk.vel_m_s).max(axis=0))
            peak_a = np.maximum(peak_a, np.abs(chunk.acc_m_s2).max(axis=0))
            pos = chunk.pos_m if last_pos is None else np.vstack((last_pos, chunk.pos_m))
            # the tool path: linear axes only (a rotary axis turns the part)
            step = np.diff(pos[:, : len(config.axes)], axis=0)
            path_length += float(np.sum(np.linalg.norm(step, axis=1)))
            last_pos = chunk.pos_m[-1:]
            t_end = float(chunk.t_s[-1])
            n_samples += len(chunk)
            n_events += len(chunk.events)
            if handle is not None:
                table = np.empty((len(chunk), 2 + 3 * n_axes))
                table[:, 0] = chunk.t_s
                table[:, 1:-1:3] = chunk.pos_m
                table[:, 2:-1:3] = chunk.vel_m_s
                table[:, 3:-1:3] = chunk.acc_m_s2
                table[:, -1] = chunk.line
                np.savetxt(handle, table, fmt=["%.12g"] * (1 + 3 * n_axes) + ["%d"], delimiter=",")
    finally:
        if handle is not None:
            handle.close()
    print(f"program      {args.program}")
    print(
        f"cycle time   {t_end:.3f} s ({n_samples} samples at {config.interpolation_period_s:g} s)"
    )
    print(f"path length  {path_length * 1e3:.3f} mm (sampled)")
    print(f"events       {n_events}")
    print(f"{'axis':<6}{'peak |v| [m/s]':>16}{'[m/min]':>10}{'peak |a| [m/s^2]':>18}")
    for i, name in enumerate(axes):
        if name in ROTARY_AXIS_NAMES:  # degrees at this edge: [deg/s], [deg/min], [deg/s^2]
            v, a = np.degrees(peak_v[i]), np.degrees(peak_a[i])
            print(f"{name:<6}{v:>12.5f} deg{v * 60.0:>10.3f}{a:>14.4f} deg")
        else:
            print(f"{name:<6}{peak_v[i]:>16.5f}{peak_v[i] * 60.0:>10.3f}{peak_a[i]:>18.4f}")
    if args.out is not None:
        print(f"wrote        {args.out}")
    return 0
