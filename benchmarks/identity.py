"""Fingerprints of what every path from a G-code program to recorded samples computes.

A refactor that must not change the physics keeps every hash here: run this before and after,
the last lines must be equal. Each hash is the sha256 of the named result arrays (dtype, shape
and bytes), per path:

- `analysis`: Twin.simulate on the planned command, at the NC period and at the model's base
  period (the two ways Twin turns a record into setpoints);
- `shadow`: the shadow twin streamed with the command (with and without its velocity);
- `standin`: the stand-in answering the command in chunks;
- `lockstep`: the node set's exchange loop in one process (ControllerCore + DriveHost);
- `native_ref`: the setpoints the native backends are fed;
- `machine`: feed_twin.machine's simulate on config/machine_default.yaml;
- `bag`: `feed-twin run` (lockstep over DDS), the decoded message data of the recorded topics
  (receive times and header.frame_id left out); skipped with --no-bag, alone
  with --bag-only;
- `shadow_bag`: `feed-twin run --shadow` of the axis file (the stand-in and the twin in
  lockstep over DDS), the same for the topics such a run records the same each time
  (tests/shadow_bag_support.py: the twin's residual without its two rolling RMS values);
  with `bag`.

    .venv/bin/python benchmarks/identity.py [--no-bag | --bag-only] [--machine FILE] [--tree DIR]

`--tree DIR` hashes another checkout (its programs and configs; run with PYTHONPATH=DIR so its
feed_twin is imported), `--machine` names another machine file: two trees compare on one
machine configuration (benchmarks/before_after.py --identity).

The last line is one JSON object: path name -> hash.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROGRAMS = ("tests/fixtures/gcode/sample.ngc", "tests/fixtures/gcode/square_metric_abs.ngc")
MODELS = ("config/axis_default.yaml", "config/emps.yaml")
NC_CONFIG = "config/axis_default.yaml"  # emps.yaml has no NC: it plans with the default's
MACHINE = "config/machine_default.yaml"
# the node set's topics whose message data is the run's result (heartbeats carry wall time)
BAG_TOPICS = ("command", "drive_command", "feedback", "state", "joint_states")
# the shadow node set's (the twin's health verdicts depend on how it grouped its samples)
SHADOW_TOPICS = ("command", "joint_states", "twin/state", "twin/residual")
# fields whose last bits depend on that grouping too (rolling sums over its blocks)
GROUPED_FIELDS = ("following_error_deviation_rms", "effort_deviation_rms")


def digest(*arrays: Any) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def planned(program: str) -> tuple[np.ndarray, ...]:
    from feed_twin.gcode import load_nc_config, plan_program

    nc = load_nc_config(ROOT / NC_CONFIG)
    traj = plan_program(ROOT / program, nc)
    x, v, a = traj.axis(nc.twin_axis)
    return traj.t_s, x, v, a, traj.line


def analysis(model: str, program: str) -> dict[str, str]:
    from feed_twin.analysis.twin import Drive, ModelDoc, Twin

    twin = Twin.compile(ModelDoc.load(ROOT / model))
    t, x, v, a, _ = planned(program)
    out: dict[str, str] = {}
    h = twin.base_period_s
    fine = t[0] + h * np.arange(round((t[-1] - t[0]) / h) + 1)
    for name, grid in (("nc_period", t), ("base_period", fine)):
        drive = Drive(
            t_s=grid,
            pos_ref_m=np.interp(grid, t, x),
            vel_ref_m_s=np.interp(grid, t, v),
            acc_ref_m_s2=np.interp(grid, t, a),
            effort_add=None,
            force_ext_N=None,
            x0_m=float(x[0]),
            sensor="motor_encoder",
        )
        sim = twin.simulate(drive, twin.nominal[None, :])
        extra = () if sim.voltage_q is None else (sim.voltage_q,)
        out[name] = digest(sim.x_m, sim.effort, *extra)
    return out


def standin(model: str, program: str) -> tuple[str, tuple[np.ndarray, np.ndarray]]:
    from feed_twin.analysis.synthetic import Unmodelled
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.shadow.standin import StandIn

    t, x, v, a, _ = planned(program)
    period = float(t[1] - t[0])
    machine = StandIn(
        ModelDoc.load(ROOT / model),
        hidden={},
        unmodelled=Unmodelled(),
        sample_period_s=period,
        x0_m=float(x[0]),
    )
    xm, em = np.zeros_like(t), np.zeros_like(t)
    for k0 in range(0, len(t), 100):
        sl = slice(k0, k0 + 100)
        xm[sl], em[sl] = machine.step(x[sl], v[sl], a[sl])
    return digest(xm, em), (xm, em)


def shadow(model: str, program: str, measured: tuple[np.ndarray, np.ndarray]) -> dict[str, str]:
    from feed_twin.analysis.twin import ModelDoc, Twin
    from feed_twin.shadow.config import load_shadow_config
    from feed_twin.shadow.standin import EFFORT_SAMPLE
    from feed_twin.shadow.twin import ResidualBlock, ShadowTwin

    t, x, v, _, _ = planned(program)
    # the default axis's shadow section for both models: the twin's samples depend on its
    # sample period (1 ms) alone, the limits only judge them
    config = load_shadow_config(ROOT / NC_CONFIG)
    doc = ModelDoc.load(ROOT / model)
    out: dict[str, str] = {}
    for with_velocity in (True, False):
        twin = ShadowTwin(
            Twin.compile(doc),
            config,
            command_velocity=with_velocity,
            travel_m=1.0,
            effort_sample=EFFORT_SAMPLE,  # the stand-in's
        )
        blocks = []
        for k in range(len(t)):
            twin.push_command(t[k], x[k], v[k] if with_velocity else None)
            twin.push_measured(t[k], measured[0][k], measured[1][k])
            if k % 37 == 0 and (b := twin.process()) is not None:
                blocks.append(b)
        if (b := twin.process(final=True)) is not None:
            blocks.append(b)
        got = ResidualBlock.concat(blocks)
        out["velocity" if with_velocity else "position"] = digest(got.x_twin_m, got.effort_twin)
    return out


def lockstep(program: str) -> str:
    from feed_twin.gcode import load_nc_config, plan_program
    from feed_twin.nodeset.drive_host import Lockstep
    from feed_twin.nodeset.wire import NS_PER_S

    config = ROOT / NC_CONFIG
    lockstep = Lockstep.for_config(config)
    traj = plan_program(ROOT / program, load_nc_config(config))
    until = round((traj.t_s[-1] + lockstep.ros.settle_s) * NS_PER_S)
    samples = lockstep.run_trajectory(traj, until_ns=until)
    names = sorted(samples[0].truth)
    return digest(
        np.array([s.t_ns for s in samples]),
        np.array([[s.truth[n] for n in names] for s in samples]),
        np.array([s.meas for s in samples]),
    )


def native_ref(program: str) -> str:
    from feed_twin.native.program import program_ref

    return digest(program_ref(ROOT / program, 1.25e-4, ROOT / NC_CONFIG))


def machine(program: str, config: Path) -> str:
    from feed_twin.machine.config import load_machine_config
    from feed_twin.machine.simulate import simulate_machine

    run = simulate_machine(load_machine_config(config), ROOT / program)
    arrays = [run.t_s, run.command, run.command_vel, run.command_acc, run.actual]
    for axis in sorted(run.signals):
        arrays += [run.signals[axis][n] for n in sorted(run.signals[axis])]
    return digest(*arrays)


def _fields(msg: Any, left_out: tuple[str, ...] = ()) -> Any:
    """A decoded message as plain values (field order kept), for hashing; without the frame_id,
    which carried a token new in every run (the run's signatures now stay out of the bag), and
    the fields `left_out`."""
    slots = getattr(msg, "__slots__", None)
    if slots is None and hasattr(msg, "__dict__"):
        slots = list(vars(msg))
    if slots is not None:
        skip = ("frame_id", *left_out)
        return [(s, _fields(getattr(msg, s))) for s in slots if s not in skip]
    if isinstance(msg, list | tuple):
        return [_fields(m) for m in msg]
    if isinstance(msg, float):
        return msg.hex()
    return msg


def bag(program: str, *, shadow: bool = False) -> dict[str, str]:
    """The hashes of the recorded topics of `feed-twin run` (`shadow`: with --shadow)."""
    from feed_twin.io.bag import BagReader
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.nodeset.topics import AxisTopics

    ros = load_node_set_config(ROOT / NC_CONFIG)
    namespace = AxisTopics(machine=ros.machine, axis=ros.axis).namespace
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            str(Path(sys.executable).parent / "feed-twin"), "run", str(ROOT / program),
            "--config", str(ROOT / NC_CONFIG), "--out", tmp, "--name", "identity", "--json",
            *(["--shadow"] if shadow else []),
        ]  # fmt: skip
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)
        if done.returncode != 0:
            raise RuntimeError(f"feed-twin run failed: {done.stderr[-2000:]}")
        path = json.loads(done.stdout.strip().splitlines()[-1])["bag"]
        reader = BagReader(path)
        out = {}
        for topic in SHADOW_TOPICS if shadow else BAG_TOPICS:
            messages = reader.messages([f"{namespace}/{topic}"])
            text = repr([_fields(m.msg, GROUPED_FIELDS) for m in messages])
            out[topic] = hashlib.sha256(text.encode()).hexdigest()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--no-bag", action="store_true", help="skip the node-set run over DDS")
    which.add_argument("--bag-only", action="store_true", help="only the node-set run over DDS")
    parser.add_argument(
        "--machine", type=Path, help=f"machine file (default: the tree's {MACHINE})"
    )
    parser.add_argument(
        "--tree",
        type=Path,
        help="another checkout whose programs and configs to read; its feed_twin must be the one "
        "imported (PYTHONPATH=TREE)",
    )
    args = parser.parse_args()
    if args.tree is not None:
        global ROOT
        ROOT = args.tree.resolve()
        import feed_twin

        if Path(feed_twin.__file__).resolve().parent != ROOT / "feed_twin":
            parser.error(f"--tree {ROOT}: feed_twin is imported from {feed_twin.__file__}")
    if args.machine is None:
        args.machine = ROOT / MACHINE
    hashes: dict[str, str] = {}
    for program in () if args.bag_only else PROGRAMS:
        stem = Path(program).stem
        for model in MODELS:
            tag = f"{stem}/{Path(model).stem}"
            for name, value in analysis(model, program).items():
                hashes[f"analysis/{tag}/{name}"] = value
            hashes[f"standin/{tag}"], measured = standin(model, program)
            for name, value in shadow(model, program, measured).items():
                hashes[f"shadow/{tag}/{name}"] = value
        hashes[f"lockstep/{stem}"] = lockstep(program)
        hashes[f"native_ref/{stem}"] = native_ref(program)
        hashes[f"machine/{stem}"] = machine(program, args.machine)
    if not args.no_bag:
        for name, value in bag(PROGRAMS[1]).items():
            hashes[f"bag/{Path(PROGRAMS[1]).stem}/{name}"] = value
        for name, value in bag(PROGRAMS[0], shadow=True).items():
            hashes[f"shadow_bag/{Path(PROGRAMS[0]).stem}/{name}"] = value
    for name, value in hashes.items():
        print(f"{name:48s} {value[:16]}")
    print(json.dumps(hashes))


if __name__ == "__main__":
    main()
