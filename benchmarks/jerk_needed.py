"""What jerk limit the default axis's dynamics call for, and what the peer corpus needs.

1. The axis's modes: the mechanical chain of `config/axis_default.yaml` linearised at table
   positions over its travel while it moves at a feed (`feed-twin model`: central-difference
   Jacobian of the plant's own right-hand side, backlash closed, screw lossless, electrical
   states frozen as under a current-controlled drive), its eigenvalues. FIR interpolation
   (Tajima and Sencer, Precision Engineering 2018) sets the filter time T = A / J to the period
   of the dominant mode, where the moving average's first zero cancels its excitation:
   J = A f1, with A the twin axis's a_max.
2. Per program of the peer corpus: the lowest jerk limit at which the floor of the jerk
   profile's time (`feed_twin.gcode.jerk_floor`: our trapezoid's time plus what a jerk limit
   must add at its near-stops) is 1.10x LinuxCNC's time. Every axis's j_max is scaled by one
   factor (their ratios kept) and the factor bisected; the figure is the twin axis's j_max.
   The floor ignores a curve's own jerk, so this is a lower bound on what a plan needs.

LinuxCNC's trajectories come from a cache directory of `benchmarks/linuxcnc_peer.py`
(`--linuxcnc-cache DIR`; a program not in it runs on LinuxCNC, about 20 s each).

    .venv/bin/python benchmarks/jerk_needed.py --linuxcnc-cache DIR [-k NAME]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from linuxcnc_peer import CORPUS, ROOT, cached_linuxcnc, peer_machine

from feed_twin.gcode import GcodeError, NcConfig, plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.jerk_floor import jerk_floor_extra
from feed_twin.gcode.metrics import trajectory_figures
from feed_twin.linuxcnc.machine import machine_for_config
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.model_cli import modes

TARGET = 1.10  # the jerk profile's time over LinuxCNC's that issue 30 asks for
POSITIONS = 9  # table positions over the travel at which the modes are computed
FEED_M_S = 0.05  # [m/s] the feed while linearising (friction regularised, not locked)
SCALE_LO, SCALE_HI = 1e-3, 1e3  # bisection bracket of the j_max factor
BISECTIONS = 40


def first_modes(config: Path, nc: NcConfig) -> list[tuple[float, float, float]]:
    """(table position [m], first mode [Hz], its damping ratio) over the twin axis's travel."""
    axis = load_axis_config(config)
    index = nc.axis_names.index(nc.twin_axis)
    lo, hi = nc.travel[index]
    out = []
    for position in np.linspace(lo, hi, POSITIONS):
        f1, zeta = modes(axis, float(position), FEED_M_S)[0]
        out.append((float(position), f1, zeta))
    return out


def needed_jerk(trapezoid_time: float, trapezoid, nc: NcConfig, reference_time: float) -> float:
    """[m/s^3] the twin axis's j_max (all axes scaled alike) at which the floor is TARGET times
    `reference_time`; inf where even no jerk limit (the trapezoid) is above it."""
    a_max, j_max = np.array(nc.a_max), np.array(nc.j_max)
    goal = TARGET * reference_time

    def floor(scale: float) -> float:
        return trapezoid_time + jerk_floor_extra(trapezoid, a_max, j_max * scale)[0]

    if floor(SCALE_HI) > goal:
        return math.inf
    lo, hi = math.log(SCALE_LO), math.log(SCALE_HI)
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        if floor(math.exp(mid)) > goal:
            lo = mid
        else:
            hi = mid
    return float(j_max[nc.axis_names.index(nc.twin_axis)] * math.exp(hi))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "axis_default.yaml")
    parser.add_argument("-k", dest="only", default="", help="only programs whose name has this")
    parser.add_argument("--linuxcnc-cache", type=Path, required=True)
    args = parser.parse_args(argv)
    nc, servo = machine_for_config(args.config)
    index = nc.axis_names.index(nc.twin_axis)
    a_twin, j_twin = nc.a_max[index], nc.j_max[index]
    found = first_modes(args.config, nc)
    print(f"first mode of the {nc.twin_axis} axis over its travel (a_max {a_twin} m/s^2):")
    for position, f1, zeta in found:
        print(
            f"  table at {position:.3f} m: {f1:6.1f} Hz (zeta {zeta:.3f}): T = 1/f1 = "
            f"{1e3 / f1:.2f} ms, J = A f1 = {a_twin * f1:.0f} m/s^3"
        )
    f_lo = min(f for _, f, _ in found)
    f_hi = max(f for _, f, _ in found)
    print(f"configured j_max {j_twin} m/s^3: T = A/J = {1e3 * a_twin / j_twin:.1f} ms")
    machine = peer_machine(Path(tempfile.mkdtemp(prefix="feed_twin-jerk-")), nc, servo)
    trapezoid_nc = dataclasses.replace(nc, profile="trapezoid")
    per_program: dict[str, float | None] = {}
    print(f"lowest {nc.twin_axis} j_max [m/s^3] at which the floor is {TARGET}x LinuxCNC's:")
    for program in sorted(CORPUS.glob("*.ngc")):
        if args.only not in program.name:
            continue
        reference = cached_linuxcnc(program, nc, servo, machine, args.linuxcnc_cache)
        try:
            trapezoid = plan_program(program, trapezoid_nc)
            segments = programmed_path(program, nc)
        except GcodeError as exc:
            print(f"  {program.stem}: {exc}")
            continue
        if isinstance(reference, str):
            print(f"  {program.stem}: LinuxCNC: {reference}")
            continue
        t_ref = trajectory_figures(reference, segments).program_time_s
        t_trap = trajectory_figures(trapezoid, segments).program_time_s
        j_needed = needed_jerk(t_trap, trapezoid, nc, t_ref)
        per_program[program.stem] = j_needed if math.isfinite(j_needed) else None
        print(f"  {program.stem:<24} {j_needed:8.1f}")
    print(
        json.dumps(
            {
                "benchmark": "jerk_needed",
                "twin_axis": nc.twin_axis,
                "a_max_m_s2": a_twin,
                "j_max_m_s3": j_twin,
                "first_mode_hz": [round(f, 1) for _, f, _ in found],
                "jerk_from_mode_m_s3": [round(a_twin * f_lo, 1), round(a_twin * f_hi, 1)],
                "jerk_for_floor_m_s3": per_program,
            }
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
