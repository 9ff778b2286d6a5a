"""The one path from a G-code program to recorded signals, in-process.

    axis = load_axis_config("config/axis_default.yaml")
    run = simulate_program(axis, "part.ngc")
    run.following_error("X"), run.signal("X", "motor.i_q")

`simulate_program` plans the program on the configuration's NC (feed_twin.gcode: lexer ->
modal interpreter -> planner -> sampled trajectory), turns each simulated axis's column into the
engine's setpoint rows (`nc_reference`), runs one closed-loop engine per simulated axis and
returns the NC's command beside the engines' recorded signals on the NC's sample grid.

The NC command of sample j (position, and velocity and acceleration as feed-forward, held over
its period as the drive's setpoint: one input row the kernel holds for dec ticks) drives base
ticks [j dec, (j+1) dec), and what the engine records at tick j dec is the axis at t_j: every
axis meets the others at every NC sample. The axes advance side by side in chunks, and axes
with the same sensor noise read it from one table (`follow`). Axes
without a plant (rotary axes, or those a machine leaves out) are their command. The plant names
its table `table`, the machine coordinate `table.s` (the axis files' convention).

Callers that receive NC samples one at a time or in chunks (the node set's controller, the
shadow twin, the stand-in, the discrepancy workflow's record replay) put them into the same
setpoint slots with `set_nc_reference` / `nc_reference`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from feed_twin.core import signals
from feed_twin.core.config import ConfigError
from feed_twin.gcode.config import NcConfig, nc_config_from_mapping
from feed_twin.gcode.planner import plan_program
from feed_twin.gcode.trajectory import SampledTrajectory
from feed_twin.sim.config import AxisConfig, build_engine
from feed_twin.sim.engine import Engine, SimResult

# NC samples every axis advances before the next takes its turn: 65 536 base ticks at 1 ms / 16 kHz,
# a noise table of 1.5 MB (three current sensors)
CHUNK_SAMPLES = 4096
TABLE_BODY = "table"
TABLE_POSITION = "table.s"
# recorded when the plant has them: the table's motion, the drive's setpoint and its own
# following error, the torque-forming current
DEFAULT_RECORD = (
    TABLE_POSITION,
    "table.v",
    "table.a",
    "out.pos_ref_m",
    "out.following_error_m",
    "motor.i_q",
)


class MachineLike(Protocol):
    """What simulate_program reads of a machine (feed_twin.machine.config.MachineConfig)."""

    @property
    def nc(self) -> NcConfig: ...

    @property
    def axes(self) -> Mapping[str, AxisConfig]: ...


def set_nc_reference(
    ref: np.ndarray,
    position_m: float | np.ndarray,
    velocity_m_s: float | np.ndarray,
    acceleration_m_s2: float | np.ndarray,
) -> None:
    """Write NC setpoints into the cascade's REF_* vector `ref` (one row, or (n, REF_SIZE) with
    one value per row): the position loop's setpoint and its velocity and acceleration
    feed-forward. The other slots are left as they are."""
    if ref.ndim == 1:  # plain indices: the node set's controller writes one row per exchange
        ref[signals.REF_POS_M] = position_m
        ref[signals.REF_VEL_M_S] = velocity_m_s
        ref[signals.REF_ACC_M_S2] = acceleration_m_s2
        return
    ref[:, signals.REF_POS_M] = position_m
    ref[:, signals.REF_VEL_M_S] = velocity_m_s
    ref[:, signals.REF_ACC_M_S2] = acceleration_m_s2


def nc_reference(
    position_m: np.ndarray, velocity_m_s: np.ndarray, acceleration_m_s2: np.ndarray, dec: int
) -> np.ndarray:
    """(n dec, REF_SIZE): the n NC samples as engine setpoint rows, each held for the `dec`
    base ticks of its period (a drive holds a fieldbus setpoint until the next one)."""
    ref = np.zeros((len(position_m) * dec, signals.REF_SIZE))
    set_nc_reference(
        ref,
        np.repeat(position_m, dec),
        np.repeat(velocity_m_s, dec),
        np.repeat(acceleration_m_s2, dec),
    )
    return ref


@dataclass(frozen=True, kw_only=True)
class ProgramRun:
    """Command and twin of every NC axis on the NC's sample grid."""

    axes: tuple[str, ...]  # every NC axis (linear first)
    simulated: tuple[str, ...]  # those with a plant
    t_s: np.ndarray  # (n,) [s]
    line: np.ndarray  # (n,) program line of the command
    command: np.ndarray  # (n, axes) [m or rad] the NC's positions
    command_vel: np.ndarray  # (n, axes) [m/s or rad/s] the NC's velocities
    command_acc: np.ndarray  # (n, axes) [m/s^2 or rad/s^2] the NC's accelerations
    actual: np.ndarray  # (n, axes) [m or rad] the twins' table positions; commands elsewhere
    engine_wall_s: float  # [s] wall-clock time the engines took, all axes
    engine_cpu_s: float  # [s] process CPU time they took (what other jobs on the core do not add)
    signals: dict[str, dict[str, np.ndarray]]  # axis -> engine signal -> (n,) at the samples

    def _index(self, axis: str) -> int:
        if axis not in self.axes:
            raise KeyError(f"axis {axis!r}: not an NC axis (axes: {', '.join(self.axes)})")
        return self.axes.index(axis)

    def position(self, axis: str) -> np.ndarray:
        """[m or rad] the twin's table position (the command where the axis has no plant)."""
        return self.actual[:, self._index(axis)]

    def commanded(self, axis: str) -> np.ndarray:
        """[m or rad] the NC's position."""
        return self.command[:, self._index(axis)]

    def following_error(self, axis: str) -> np.ndarray:
        """[m] command minus the twin's position, per sample."""
        i = self._index(axis)
        return self.command[:, i] - self.actual[:, i]

    def signal(self, axis: str, name: str) -> np.ndarray:
        """One recorded engine signal of a simulated axis (e.g. "table.v", "motor.i_q")."""
        recorded = self.signals.get(axis)
        if recorded is None:
            raise KeyError(f"axis {axis!r}: not simulated (simulated: {', '.join(self.simulated)})")
        if name not in recorded:
            raise KeyError(
                f"axis {axis}: signal {name!r} was not recorded (recorded: {', '.join(recorded)})"
            )
        return recorded[name]


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


def _nc_and_axes(config: AxisConfig | MachineLike) -> tuple[NcConfig, Mapping[str, AxisConfig]]:
    if isinstance(config, AxisConfig):
        if config.nc is None:
            raise ConfigError(f"{config.source}: simulating a program needs an nc: section")
        nc = nc_config_from_mapping(config.nc, source=config.source)
        return nc, {nc.twin_axis: config}
    return config.nc, config.axes


def axis_engine(
    name: str,
    axis: AxisConfig,
    nc: NcConfig,
    *,
    record: Sequence[str],
    preroll_s: float,
) -> Engine:
    """The closed-loop engine of NC axis `name`, recording at the NC period, at the NC's start
    position after `preroll_s` of holding it (a vertical axis sags until its integrator carries
    the weight; a machine that starts a program has long done that)."""
    period = nc.interpolation_period_s
    known = build_engine(axis, output_period_s=period).all_names
    wanted = list(dict.fromkeys(n for n in (TABLE_POSITION, *record) if n in known))
    engine = build_engine(axis, record=wanted, output_period_s=period)
    start = nc.start_position[nc.axis_index(name)]
    try:
        engine.reset(positions={TABLE_BODY: start})
    except KeyError as exc:
        raise ConfigError(f"{axis.source}: axis {name}: {exc.args[0]}") from None
    ticks = round(preroll_s / period) * engine.dec
    if ticks:
        rest = np.zeros((1, signals.REF_SIZE))
        rest[0, signals.REF_POS_M] = start
        engine.advance(ticks, ref=rest, hold=ticks)
    return engine


def follow(
    engines: Mapping[str, Engine],
    traj: SampledTrajectory,
    on_progress: Callable[[float], None] | None = None,
) -> dict[str, dict[str, np.ndarray]]:
    """Each engine's recorded signals at every NC sample of `traj`, following its axis's column
    (the engines' keys): the axes advance side by side, CHUNK_SAMPLES NC samples at a time.

    Engines that draw the same sensor noise (equal `Engine.noise_key`, e.g. axes built from one
    drive file with one seed) read one table of it, drawn once per chunk: an axis drawing its
    own spends a few per cent of its ticks on draws the others repeat. The chunks bound the
    table (one row of samples per tick); the results are the bits of one long run each.
    `on_progress` hears the simulated time [s] reached after each chunk."""
    refs = {name: nc_reference(*traj.axis(name), 1) for name in engines}  # one row per sample
    keys = {name: (e.noise_key, e.k, e.dec) for name, e in engines.items()}
    shared = {key for key in keys.values() if list(keys.values()).count(key) > 1}
    parts: dict[str, list[SimResult]] = {name: [] for name in engines}
    for a in range(0, max(len(traj), 1), CHUNK_SAMPLES):
        b = min(a + CHUNK_SAMPLES, len(traj))
        tables: dict[tuple, np.ndarray] = {}
        for name, engine in engines.items():
            n = (b - a) * engine.dec
            normals = None
            if keys[name] in shared:
                if keys[name] not in tables:
                    tables[keys[name]] = engine.standard_normals(n)
                normals = tables[keys[name]]
            part = engine.advance(n, ref=refs[name][a:b], hold=engine.dec, normals=normals)
            parts[name].append(part)
        if on_progress is not None and b > 0:
            on_progress(float(traj.t_s[b - 1]))
    return {name: SimResult.concat(chunks).as_dict() for name, chunks in parts.items()}


def simulate_program(
    config: AxisConfig | MachineLike,
    program: str | Path,
    *,
    settle_s: float = 0.2,
    preroll_s: float = 0.5,
    record: Sequence[str] = DEFAULT_RECORD,
    on_progress: Callable[[float], None] | None = None,
) -> ProgramRun:
    """Plan `program` on the NC of `config` (an axis file with an nc: section, or a machine)
    and run every simulated axis on it (module docstring). `settle_s` [s] of rest follow the
    program; each axis holds its start position for `preroll_s` [s] before it; `record` names
    the engine signals to keep where the plant has them (the table position always);
    `on_progress` hears the simulated time [s] reached as the axes advance."""
    nc, axes = _nc_and_axes(config)
    traj = with_settle(plan_program(program, nc), settle_s)
    engines = {
        name: axis_engine(name, axis, nc, record=record, preroll_s=preroll_s)
        for name, axis in axes.items()
    }
    actual = traj.pos_m.copy()
    began, began_cpu = time.perf_counter(), time.process_time()
    recorded = follow(engines, traj, on_progress)
    for name in engines:
        actual[:, nc.axis_index(name)] = recorded[name][TABLE_POSITION]
    wall, cpu = time.perf_counter() - began, time.process_time() - began_cpu
    return ProgramRun(
        axes=nc.axis_names,
        simulated=tuple(engines),
        t_s=traj.t_s,
        line=traj.line,
        command=traj.pos_m,
        command_vel=traj.vel_m_s,
        command_acc=traj.acc_m_s2,
        actual=actual,
        engine_wall_s=wall,
        engine_cpu_s=cpu,
        signals=recorded,
    )
