"""`feed-twin model --config CONFIG`: the assembled plant of an axis YAML and its modes.

Prints the generalized coordinates (which bodies move together, effective inertia), the state
and parameter layout sizes, and the eigenfrequencies and damping ratios of the mechanical chain
linearised at table positions while the axis moves at a feed (backlash closed, screw lossless,
electrical states frozen as under a current-controlled drive; at standstill the regularised
friction would lock the bodies and hide the modes), plus the fixed-step figure h*omega_max.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from feed_twin.sim.config import load_axis_config


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="axis YAML (plant: and engine: sections)")
    parser.add_argument(
        "--positions",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="S",
        help="positions [m] of the last body (the table) at which to linearise; default 0",
    )
    parser.add_argument(
        "--velocity",
        type=float,
        default=0.05,
        metavar="V",
        help="velocity [m/s] of the last body while linearising; default 0.05",
    )


def modes(axis, position: float, velocity: float) -> list[tuple[float, float]]:
    """(frequency [Hz], damping ratio) of the mechanical chain at `position` and `velocity` of
    the last body, lowest first."""
    # At rest with relaxed springs a backlash sits in the middle of its gap (the table would be
    # decoupled) and a lossy screw switches efficiency with the sign of the transmitted power
    # (no derivative at zero load): the modes are those of the loaded chain, contacts closed
    # and the screw lossless.
    changes: dict[str, dict[str, float]] = {}
    for name, comp in axis.plant.components.items():
        if getattr(comp, "lossy", False):
            changes[name] = {"efficiency": 1.0}
        if comp.TYPE == "Backlash":
            changes[name] = {"gap": 0.0}
    plant = axis.plant.with_params(**changes)
    body = plant.coordinates[-1].name
    x = plant.initial_state({body: position})
    ahead = plant.initial_state({body: position + velocity})  # positions scale linearly
    for c in plant.coordinates:
        i, j = plant.state_index[c.velocity_state], plant.state_index[c.position_state]
        x[i] = ahead[j] - x[j]
    names = [n for c in plant.coordinates for n in (c.position_state, c.velocity_state)]
    lam = np.linalg.eigvals(plant.linearize(x, plant.nominal_params(), states=names))
    out = []
    for value in lam:
        if value.imag > 1e-6:
            omega = abs(value)
            out.append((omega / (2.0 * math.pi), -value.real / omega))
    return sorted(out)


def main(args: argparse.Namespace) -> int:
    axis = load_axis_config(args.config)
    plant = axis.plant
    p = plant.nominal_params()
    print(
        f"{args.config}: {len(plant.components)} components, {len(plant.state_names)} states, "
        f"{len(plant.param_names)} parameter slots"
    )
    for c in plant.coordinates:
        inertia = 1.0 / p[plant.param_index[f"derived.inv_inertia.{c.name}"]]
        unit = "kg m^2" if c.kind == "rotational" else "kg"
        ports = sorted({pt for n in c.nodes for pt in plant.nodes[n].ports})
        print(f"  coordinate {c.name:<12} {inertia:.4g} {unit:<6} {', '.join(ports)}")
    h = axis.engine.base_period_s / axis.engine.substeps
    for position in args.positions:
        found = modes(axis, position, args.velocity)
        text = ", ".join(f"{f:.1f} Hz (zeta {z:.3f})" for f, z in found)
        print(f"  modes at {position:+.3f} m: {text}")
        if found:
            print(f"  h*omega_max = {h * 2.0 * math.pi * found[-1][0]:.2f} (RK4 limit 2.8)")
    return 0
