"""The node set's speed overshoot against the jerk filter's time, with and without symmetrization.

The 10 mm F3000 move of tests/test_nodes_run.py (`tests/nodes_support.SHORT_PROGRAM`) through
the node set's exchanges in-process (`drive_host.Lockstep`: the same `ControllerCore` and
`DriveHost` as the controller and sim nodes, equal to them to 1e-9 m), with every axis's
j_max = a_max / T for each filter time T, and the controller node's feed-forward symmetrization
(feed_twin/nodeset/reference_delay.py) on and off. Per run: the peak speed of the table and of
the motor (load side) over the planned 50 mm/s, and the loop's following error (against the
setpoint the loop compares with: the NC's, D_x late when symmetrized).

    .venv/bin/python benchmarks/node_feed_forward.py [--T-ms 9 15 20 50]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.nodeset.config import NodeLoopGains, load_node_set_config
from feed_twin.nodeset.drive_host import Lockstep
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.sim.config import load_axis_config

ROOT = Path(__file__).resolve().parent.parent
AXIS_CONFIG = ROOT / "config" / "axis_default.yaml"
SHORT_PROGRAM = "%\nG21 G90 G54 G64\nG1 X10 F3000\nM30\n%\n"  # tests/nodes_support.py's


def run(T_s: float, symmetrize: bool) -> dict:
    ros = load_node_set_config(AXIS_CONFIG)
    axis = load_axis_config(AXIS_CONFIG)
    assert axis.controller is not None
    nc = load_nc_config(AXIS_CONFIG)
    # a hair above a_max / T, as config/axis_default.yaml rounds up: A/J within T's periods
    axes = tuple(
        dataclasses.replace(a, j_max_m_s3=a.a_max_m_s2 / T_s * (1.0 + 1e-5)) for a in nc.axes
    )
    nc = dataclasses.replace(nc, axes=axes)
    trajectory = plan_program(SHORT_PROGRAM, nc)
    _, v, _ = trajectory.axis("X")
    until = round((trajectory.t_s[-1] + ros.settle_s) * NS_PER_S)
    gains = NodeLoopGains(symmetrize_feed_forward=symmetrize)
    samples = Lockstep.for_config(AXIS_CONFIG, gains=gains).run_trajectory(
        trajectory, until_ns=until
    )
    lead = axis.controller.drive.lead_m
    table = np.array([s.truth["table_velocity"] for s in samples])
    motor = np.array([s.truth["motor_velocity"] for s in samples]) * lead / (2.0 * math.pi)
    error = np.array([s.truth["following_error"] for s in samples])
    peak = float(np.max(np.abs(v)))
    return {
        "T_ms": round(T_s * 1e3, 3),
        "symmetrized": symmetrize,
        "table_overshoot_pct": round(100.0 * (float(np.max(table)) / peak - 1.0), 2),
        "motor_overshoot_pct": round(100.0 * (float(np.max(motor)) / peak - 1.0), 2),
        "following_error_max_um": round(float(np.max(np.abs(error))) * 1e6, 1),
        "following_error_rms_um": round(float(np.sqrt(np.mean(error**2))) * 1e6, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--T-ms", type=float, nargs="+", default=[9.0, 15.0, 20.0, 50.0])
    args = parser.parse_args()
    rows = []
    for T_ms in args.T_ms:
        for symmetrize in (False, True):
            row = run(T_ms * 1e-3, symmetrize)
            rows.append(row)
            print(
                f"T = {row['T_ms']:5.1f} ms, symmetrized {str(symmetrize):5}: speed overshoot "
                f"table {row['table_overshoot_pct']:6.2f} %, motor "
                f"{row['motor_overshoot_pct']:6.2f} %; following error max "
                f"{row['following_error_max_um']:6.1f} um, RMS {row['following_error_rms_um']} um",
                flush=True,
            )
    print(json.dumps({"runs": rows}))


if __name__ == "__main__":
    main()
