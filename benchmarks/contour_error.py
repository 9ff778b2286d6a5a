"""Contour error of the machine twin on a circle, against two matched first-order loops.

A 100 mm diameter circle in XY (G3, three turns from rest; the middle turn is measured) on
config/machine_default.yaml, all three axes simulated in-process (feed_twin.machine.simulate;
Z holds its weight), at 2000, 4000 and 6000 mm/min:
- feed-forward off (velocity_ff = acceleration_ff = 0; the following-error trip raised, v/Kv
  reaches 3.3 mm): the radius reduction, the mean over the turn of |command - centre| minus
  |twin - centre| (so that the NC's chord polygon, up to 2 um inside the circle, cancels),
  against the closed form of two matched P position loops with ideal velocity loops,
  dR = v^2 / (2 R Kv^2) (`ratio`: measured / closed form; the goal is within 5 %); and the
  mean and largest normal contour error (distance from the programmed circle) beside it;
- feed-forward on (as configured): the same, and the reduction the feed-forward buys
  (off / on, of the mean normal contour error).
The NC's jerk limits are raised (x3) for this benchmark: with the default limits the planner's
chained arc blends run 6000 mm/min up to 8 % below F and unevenly on this circle, and the closed
form needs a constant speed (the drives keep their 3 m/s^2: 12 m/s^2 trips X on the rapid).
ff_reduction: off / on of the mean normal contour error, which with the feed-forward on is
mostly the NC's own chord polygon; ff_reduction_radius: of the radius reduction (on: its
magnitude; the twin runs slightly outside the command). realtime_factor_3_axes: simulated
seconds per wall-clock second of the three engines (one thread), best over the six runs; _cpu:
per second of process CPU time, which other jobs on a shared core do not add. What it counts:
the engines advancing every axis over the program (setpoint rows, the shared noise tables, the
compiled loop, the recorded signals); not the kernels' compile (a warm-up run first: about 12 s
per kernel when new, then milliseconds from the disk cache), the planning, the engines' build
and 0.5 s pre-roll, nor the contour error. realtime_factor_whole_run: the same simulated time
per wall-clock second of the whole simulate_machine call (planning, engines, contour error).
--inline compiles each axis's parameter values into its kernel (about 10 % faster per tick; one
kernel per distinct axis, cached on disk).

    .venv/bin/python benchmarks/contour_error.py [--inline]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from feed_twin.machine.config import MachineConfig, load_machine_config
from feed_twin.machine.simulate import simulate_machine

ROOT = Path(__file__).resolve().parents[1]
R = 0.05  # [m]
FEEDS_MM_MIN = (2000.0, 4000.0, 6000.0)
JERK_FACTOR = 3.0


MEASURED_LINE = 4  # the middle turn


def circle(feed_mm_min: float) -> str:
    turn = "G3 X50 Y0 I-50 J0"
    return f"G90 G17 G21 G54\nG0 X50 Y0\n{turn} F{feed_mm_min:g}\n{turn}\n{turn}\nM2\n"


def inlined(machine: MachineConfig) -> MachineConfig:
    """The machine with each axis's plant parameters compiled into its kernel (sim.config)."""
    axes = {
        name: dataclasses.replace(
            axis, engine=dataclasses.replace(axis.engine, inline_parameters=True)
        )
        for name, axis in machine.axes.items()
    }
    return dataclasses.replace(machine, axes=axes)


def without_feed_forward(machine: MachineConfig) -> MachineConfig:
    axes = {}
    for name, axis in machine.axes.items():
        position = dataclasses.replace(
            axis.controller.position,
            velocity_ff=0.0,
            acceleration_ff=0.0,
            following_error_limit_m=0.02,
        )
        controller = dataclasses.replace(axis.controller, position=position)
        axes[name] = dataclasses.replace(axis, controller=controller)
    return dataclasses.replace(machine, axes=axes)


def middle_turn(machine: MachineConfig, feed: float) -> dict[str, float]:
    """Radius reduction, normal contour error (mean, max) [m], path speed [m/s] and the
    realtime factor of the middle turn."""
    began = time.perf_counter()
    run = simulate_machine(machine, circle(feed))
    whole = time.perf_counter() - began
    turn = run.line == MEASURED_LINE
    centre = np.array(machine.nc.work_offsets_m.G54[:2])
    rho_cmd = np.linalg.norm(run.command[turn, :2] - centre, axis=1)
    rho_twin = np.linalg.norm(run.actual[turn, :2] - centre, axis=1)
    normal = run.contour.normal_m[turn]
    speed = np.linalg.norm(np.diff(run.command[:, :2], axis=0), axis=1) / np.diff(run.t_s)
    return {
        "dR": float(np.mean(rho_cmd - rho_twin)),
        "mean": float(np.mean(normal)),
        "max": float(np.max(normal)),
        "v": float(np.median(speed[turn[1:]])),
        "factor": float(run.t_s[-1] / run.engine_wall_s),
        "factor_cpu": float(run.t_s[-1] / run.engine_cpu_s),
        "factor_whole": float(run.t_s[-1] / whole),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument(
        "--inline",
        action="store_true",
        help="compile each axis's parameter values into its kernel (engine.inline_parameters)",
    )
    args = parser.parse_args()
    base = load_machine_config(ROOT / "config" / "machine_default.yaml")
    limits = tuple(
        dataclasses.replace(a, j_max_m_s3=JERK_FACTOR * a.j_max_m_s3) for a in base.nc.axes
    )
    nc = dataclasses.replace(base.nc, axes=limits, lookahead_segments=100000)
    with_ff = dataclasses.replace(base, nc=nc)
    if args.inline:
        with_ff = inlined(with_ff)
    no_ff = without_feed_forward(with_ff)
    kv = no_ff.axes["X"].controller.position.Kv_1_s
    simulate_machine(with_ff, circle(6000.0))  # warm-up: the kernels compile or load
    rows = []
    factors = []
    factors_cpu = []
    factors_whole = []
    for feed in FEEDS_MM_MIN:
        off = middle_turn(no_ff, feed)
        on = middle_turn(with_ff, feed)
        v = off["v"]
        closed = v * v / (2.0 * R * kv * kv)
        factors += [off["factor"], on["factor"]]
        factors_cpu += [off["factor_cpu"], on["factor_cpu"]]
        factors_whole += [off["factor_whole"], on["factor_whole"]]
        row = {
            "feed_mm_min": feed,
            "path_speed_m_s": v,
            "closed_form_um": closed * 1e6,
            "ff_off_radius_reduction_um": off["dR"] * 1e6,
            "ratio": off["dR"] / closed,
            "ff_off_contour_mean_um": off["mean"] * 1e6,
            "ff_off_contour_max_um": off["max"] * 1e6,
            "ff_on_radius_reduction_um": on["dR"] * 1e6,
            "ff_on_contour_mean_um": on["mean"] * 1e6,
            "ff_on_contour_max_um": on["max"] * 1e6,
            "ff_reduction": off["mean"] / on["mean"],
            "ff_reduction_radius": off["dR"] / abs(on["dR"]),
        }
        rows.append(row)
        print(
            f"F{feed:.0f}: closed form {closed * 1e6:.2f} um, ff off dR {off['dR'] * 1e6:.2f} um "
            f"(x{off['dR'] / closed:.3f}), contour {off['mean'] * 1e6:.2f} um; ff on "
            f"{on['mean'] * 1e6:.3f} um (/{off['mean'] / on['mean']:.0f})"
        )
    figures = {
        "Kv_1_s": kv,
        "circle_diameter_mm": 2e3 * R,
        "rows": rows,
        "max_ratio_deviation": max(abs(r["ratio"] - 1.0) for r in rows),
        "realtime_factor_3_axes": max(factors),
        "realtime_factor_3_axes_median": float(np.median(factors)),
        "realtime_factor_3_axes_cpu": max(factors_cpu),
        "realtime_factor_3_axes_cpu_median": float(np.median(factors_cpu)),
        "realtime_factor_whole_run": max(factors_whole),
        "inline_parameters": args.inline,
        "load_average_1min": os.getloadavg()[0],
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
