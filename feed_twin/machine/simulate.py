"""A program on the machine twin in-process: the NC plans every axis, one engine per simulated
axis follows its column, and the tool point is measured against the programmed path.

    machine = load_machine_config("config/machine_default.yaml")
    run = simulate_machine(machine, "part.ngc")
    run.summary()["contour_error_max_m"]

Every engine runs the same samples: the NC command of sample j (position, velocity and
acceleration, held over its period as the drive's setpoint) drives ticks [j dec, (j+1) dec), and
the plant's table position recorded at tick j dec is the axis's actual position at t_j; the
axes meet at every NC sample (lockstep) because they share the grid. Axes without a plant
(rotary axes, or those left out with --axes) are their command. Each axis plant names its
table `table` with the machine coordinate `table.s` (the axis files' convention: the ROS node
set reads the same signal).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from feed_twin.core import signals
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.planner import plan_program
from feed_twin.gcode.trajectory import SampledTrajectory
from feed_twin.io.config import ConfigError
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.contour import ContourError, contour_error
from feed_twin.nodeset.split import StateSignals
from feed_twin.sim.config import build_engine
from feed_twin.sim.engine import Engine

TABLE_BODY = "table"
TABLE_POSITION = "table.s"
# what the drive reports beside the plant's truth (AxisState's setpoint and following error)
DRIVE_SIGNALS = ("out.pos_ref_m", "out.following_error_m")


@dataclass(frozen=True, kw_only=True)
class MachineRun:
    """Command and twin of every NC axis on the NC's sample grid."""

    axes: tuple[str, ...]  # every NC axis (linear first)
    simulated: tuple[str, ...]  # those with a plant
    t_s: np.ndarray  # (n,) [s]
    line: np.ndarray  # (n,) program line of the command
    command: np.ndarray  # (n, axes) [m or rad] the NC's positions
    command_vel: np.ndarray  # (n, axes) [m/s or rad/s] the NC's velocities
    command_acc: np.ndarray  # (n, axes) [m/s^2 or rad/s^2] the NC's accelerations
    actual: np.ndarray  # (n, axes) [m or rad] the twins' table positions; commands elsewhere
    contour: ContourError
    engine_wall_s: float  # [s] wall-clock time the engines took, all axes
    engine_cpu_s: float  # [s] process CPU time they took (what other jobs on the core do not add)
    signals: dict[str, dict[str, np.ndarray]]  # axis -> engine signal -> (n,) at the samples

    def following_error(self, axis: str) -> np.ndarray:
        """[m] command minus the twin's position, per sample."""
        i = self.axes.index(axis)
        return self.command[:, i] - self.actual[:, i]

    def summary(self) -> dict[str, object]:
        out: dict[str, object] = dict(self.contour.summary())
        out["following_error_max_m"] = {
            a.lower(): float(np.max(np.abs(self.following_error(a)))) for a in self.simulated
        }
        out["simulated_s"] = float(self.t_s[-1]) if len(self.t_s) else 0.0
        out["axes"] = [a.lower() for a in self.simulated]
        return out


def with_settle(traj: SampledTrajectory, settle_s: float) -> SampledTrajectory:
    """The trajectory followed by `settle_s` at rest at its last position."""
    if len(traj) == 0:
        return traj
    period = float(traj.t_s[1] - traj.t_s[0]) if len(traj) > 1 else 1e-3
    n = round(settle_s / period)
    if n <= 0:
        return traj
    pad = np.zeros((n, traj.pos_m.shape[1]))
    return SampledTrajectory(
        t_s=np.concatenate((traj.t_s, traj.t_s[-1] + period * np.arange(1, n + 1))),
        axes=traj.axes,
        pos_m=np.concatenate((traj.pos_m, pad + traj.pos_m[-1])),
        vel_m_s=np.concatenate((traj.vel_m_s, pad)),
        acc_m_s2=np.concatenate((traj.acc_m_s2, pad)),
        line=np.concatenate((traj.line, np.full(n, traj.line[-1]))),
        events=traj.events,
    )


def axis_engines(machine: MachineConfig, *, preroll_s: float = 0.5) -> dict[str, Engine]:
    """One closed-loop engine per simulated axis, recording at the NC period, at the NC's start
    position after `preroll_s` of holding it (a vertical axis sags until its integrator carries
    the weight; a machine that starts a program has long done that)."""
    period = machine.nc.interpolation_period_s
    engines = {}
    for name, axis in machine.axes.items():
        known = build_engine(axis, output_period_s=period).all_names
        wanted = (TABLE_POSITION, *DRIVE_SIGNALS, *StateSignals().names(), "table.a")
        record = list(dict.fromkeys(n for n in wanted if n in known))
        engine = build_engine(axis, record=record, output_period_s=period)
        start = machine.nc.start_position[machine.nc.axis_index(name)]
        try:
            engine.reset(positions={TABLE_BODY: start})
        except KeyError as exc:
            raise ConfigError(f"{axis.source}: axis {name}: {exc.args[0]}") from None
        hold = np.zeros((round(preroll_s / period) * engine.dec, signals.REF_SIZE))
        hold[:, signals.REF_POS_M] = start
        engine.advance(len(hold), ref=hold)
        engines[name] = engine
    return engines


def follow(engine: Engine, traj: SampledTrajectory, axis: str) -> dict[str, np.ndarray]:
    """The engine's recorded signals at every NC sample of `traj`, following its `axis`
    column."""
    pos, vel, acc = traj.axis(axis)
    dec = engine.dec
    ref = np.zeros((len(pos) * dec, signals.REF_SIZE))
    ref[:, signals.REF_POS_M] = np.repeat(pos, dec)
    ref[:, signals.REF_VEL_M_S] = np.repeat(vel, dec)
    ref[:, signals.REF_ACC_M_S2] = np.repeat(acc, dec)
    return engine.advance(len(ref), ref=ref).as_dict()


def simulate_machine(
    machine: MachineConfig, program: str | Path, *, settle_s: float = 0.2, preroll_s: float = 0.5
) -> MachineRun:
    """Plan `program` on the machine's NC, run every simulated axis, measure the contour."""
    nc = machine.nc
    traj = with_settle(plan_program(program, nc), settle_s)
    engines = axis_engines(machine, preroll_s=preroll_s)
    actual = traj.pos_m.copy()
    began, began_cpu = time.perf_counter(), time.process_time()
    recorded = {}
    for name, engine in engines.items():
        recorded[name] = follow(engine, traj, name)
        actual[:, nc.axis_index(name)] = recorded[name][TABLE_POSITION]
    wall, cpu = time.perf_counter() - began, time.process_time() - began_cpu
    n_linear = len(nc.axes)
    contour = contour_error(
        traj.t_s,
        traj.line,
        actual,
        traj.pos_m,
        traj.vel_m_s,
        programmed_path(program, nc),
        n_linear=n_linear,
    )
    return MachineRun(
        axes=nc.axis_names,
        simulated=tuple(engines),
        t_s=traj.t_s,
        line=traj.line,
        command=traj.pos_m,
        command_vel=traj.vel_m_s,
        command_acc=traj.acc_m_s2,
        actual=actual,
        contour=contour,
        engine_wall_s=wall,
        engine_cpu_s=cpu,
        signals=recorded,
    )
