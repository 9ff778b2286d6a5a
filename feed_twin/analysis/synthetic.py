"""Synthetic "measured" runs with hidden effects, for testing the workflow blind.

A truth model is the nominal model document plus
- the hidden effect(s), each set through the same component the workflow would add,
- a little unmodelled dynamics: the drive's current loop as a first-order lag (`T_lag`) that
  the nominal model does not have,
- the real sensor: the encoder with its true count (quantisation), not the fitting twin's
  smooth one,
- sensor noise on the recorded effort (a measured current is never clean).
A PMSM axis's record also carries the q-axis voltage its current controller commanded (as a
drive scope records it, with the loop's response to the truth's current-sensor noise in it).
It runs on the same engine as the twin (no second copy of the physics), driven by a G-code
program planned by feed_twin.gcode, and is written as a CSV in a machine's own units (ms, mm,
volts) with a column map, exactly as a user would bring real data. The workflow is never told
what was hidden.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from feed_twin.analysis.effects import LIBRARY
from feed_twin.analysis.model_doc import ModelDoc, model_of
from feed_twin.analysis.recorder import period_mean
from feed_twin.analysis.twin import Drive, Twin
from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.plant.effect_api import TruthFn
from feed_twin.plant.guide_friction import friction_force

# A program with moves of several lengths and feeds, reversals and dwells on one axis (X).
PROGRAM = """\
(feed_twin synthetic run: moves and reversals along X)
G21 G90 G94 G54 G64
G1 X20 F6000
G1 X60 F2400
G4 P0.15
G1 X10 F4800
G1 X35 F900
G1 X5 F3600
G4 P0.1
G1 X70 F7200
G1 X40 F1800
G1 X50 F600
G1 X0 F5400
G4 P0.1
M30
"""

NC_CONFIG = """\
nc:
  twin_axis: X
  profile: jerk
  interpolation_period_s: 0.001
  path_tolerance_m: 1.0e-5
  chord_tolerance_m: 2.0e-6
  arc_radius_tolerance_m: 1.0e-5
  lookahead_segments: 200
  block_delete: true
  dwell_p_unit: s
  start_position_m: [0.0, 0.0, 0.0]
  axes:
    - {name: X, v_max_m_s: 0.15, rapid_m_s: 0.15, a_max_m_s2: 0.8, j_max_m_s3: 40.0,
       travel_min_m: -0.01, travel_max_m: 0.3}
    - {name: Y, v_max_m_s: 0.15, rapid_m_s: 0.15, a_max_m_s2: 0.8, j_max_m_s3: 40.0,
       travel_min_m: -0.01, travel_max_m: 0.3}
    - {name: Z, v_max_m_s: 0.15, rapid_m_s: 0.15, a_max_m_s2: 0.8, j_max_m_s3: 40.0,
       travel_min_m: -0.01, travel_max_m: 0.3}
  work_offsets_m:
    G54: [0.0, 0.0, 0.0]
    G55: [0.0, 0.0, 0.0]
    G56: [0.0, 0.0, 0.0]
    G57: [0.0, 0.0, 0.0]
    G58: [0.0, 0.0, 0.0]
    G59: [0.0, 0.0, 0.0]
"""

MAP = """\
# column map of a synthetic run (written by feed_twin.analysis.synthetic)
time: {{column: time_ms, unit: ms}}
position_sensor: {sensor}
signals:
  pos_cmd_m: {{column: x_cmd_mm, unit: mm}}
  pos_meas_m: {{column: x_act_mm, unit: mm}}
  {effort}{voltage}
plausibility: {{travel_m: 1.0, max_speed_m_s: 0.5}}
"""
EFFORT_COLUMNS = {
    # canonical effort -> (file column, map entry with {gain})
    "force_cmd_N": ("u_drive_V", "force_cmd_N: {{column: u_drive_V, unit: V, gain: {gain!r}}}"),
    "current_q_A": ("i_q_A", "current_q_A: {{column: i_q_A, unit: A}}"),
}
VOLTAGE_COLUMN = "u_q_V"  # the commanded q-axis voltage of a PMSM drive [V]


# effect -> how a truth model hides it (declared by the component that carries it)
HIDDEN: dict[str, TruthFn] = {effect.name: effect.truth for effect in LIBRARY}


@dataclass(frozen=True, kw_only=True)
class Unmodelled:
    """What the truth has beyond the hidden effects."""

    current_lag_s: float = 2e-4  # [s] first-order lag of a force-source drive's current loop
    coupling_stiffness_factor: float = 0.97  # truth/nominal torsional coupling stiffness [-]
    effort_noise_std: float | None = None  # [effort unit]; None: 0.3 N or 0.01 A
    seed: int = 0  # of the noise added to the recorded effort
    # of the truth's own sensors' noise (the current ADC's, feed_twin.plant.noise): another
    # value is another realisation of the same machine, to measure what a deterministic twin
    # cannot reproduce
    sensor_seed: int = 0
    # [1] share by which the truth's guide friction grows, linearly, over the record (the
    # engine holds parameters constant: the growth acts as a force on the table)
    friction_growth: float = 0.0

    def __post_init__(self) -> None:
        require_nonnegative("current_lag_s", self.current_lag_s)
        require_positive("coupling_stiffness_factor", self.coupling_stiffness_factor)
        if self.effort_noise_std is not None:
            require_nonnegative("effort_noise_std", self.effort_noise_std)
        require_nonnegative("sensor_seed", self.sensor_seed)


def truth_model(
    nominal: ModelDoc, hidden: Mapping[str, Mapping[str, float]], unmodelled: Unmodelled
) -> ModelDoc:
    doc = nominal
    for name, params in hidden.items():
        doc = model_of(HIDDEN[name](doc, params))
    if unmodelled.current_lag_s > 0.0:
        for source in doc.of_type("EffortSource"):
            doc = doc.set(f"{source}.T_lag", unmodelled.current_lag_s)
    for coupling in doc.of_type("Coupling"):
        k = doc.get(f"{coupling}.k")
        doc = doc.set(f"{coupling}.k", k * unmodelled.coupling_stiffness_factor)
    return doc


def write_with_nc(nominal: ModelDoc, path: str | Path, nc_config: str = NC_CONFIG) -> ModelDoc:
    """The nominal model with the NC a synthetic program is planned on, written to `path`
    and loaded from there: what `diagnose --program` takes (a model's nc: section)."""
    import yaml

    Path(path).write_text(yaml.safe_dump(nominal.data | yaml.safe_load(nc_config)))
    return ModelDoc.load(path)


def command(program: str = PROGRAM, nc_config: str = NC_CONFIG) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], X position setpoint [m]) of a G-code program planned by feed_twin.gcode."""
    import yaml

    from feed_twin.gcode.config import nc_config_from_mapping
    from feed_twin.gcode.planner import plan_program

    cfg = nc_config_from_mapping(yaml.safe_load(nc_config)["nc"], source="<synthetic nc>")
    traj = plan_program(program, cfg)
    x, _, _ = traj.axis("X")
    return traj.t_s.copy(), x.copy()


def generate(
    nominal: ModelDoc,
    hidden: Mapping[str, Mapping[str, float]],
    *,
    unmodelled: Unmodelled | None = None,
    program: str = PROGRAM,
    nc_config: str = NC_CONFIG,
    start_m: float = 0.0,
) -> dict[str, np.ndarray]:
    """The columns of a synthetic record in the file's own units (see MAP)."""
    um = unmodelled or Unmodelled()
    truth = truth_model(nominal, hidden, um)
    if um.friction_growth:
        truth, _ = truth.with_table_component("friction_growth", "ExternalForce", {})
    # the lag adds a fast pole: sub-steps keep explicit RK4 well inside its stability limit
    h = float(truth.data["controller"]["base_period_s"])
    lagged = um.current_lag_s > 0 and truth.of_type("EffortSource")
    nsub = max(1, int(np.ceil(2.0 * h / um.current_lag_s))) if lagged else 1
    twin = Twin.compile(truth, smooth_sensors=False, min_substeps=nsub)
    twin.engine.seed = um.sensor_seed
    t, x_cmd = command(program, nc_config)
    x_cmd = x_cmd + start_m
    h = float(t[1] - t[0])
    n = len(t)
    drive = Drive(
        t_s=t,
        pos_ref_m=x_cmd,
        vel_ref_m_s=np.gradient(x_cmd, h),
        acc_ref_m_s2=np.gradient(np.gradient(x_cmd, h), h),
        effort_add=None,
        force_ext_N=_friction_growth(truth, t, np.gradient(x_cmd, h), um.friction_growth),
        x0_m=float(x_cmd[0]),
        sensor="motor_encoder",
    )
    out = twin.simulate(drive, twin.nominal[None, :])
    if not out.ok[0]:
        raise RuntimeError(f"the truth model {sorted(hidden)} diverged")
    rng = np.random.default_rng(um.seed)
    current = twin.effort_name == "current_q_A"
    std = um.effort_noise_std if um.effort_noise_std is not None else (0.01 if current else 0.3)
    assert out.effort is not None  # ok[0]: the truth simulated
    effort = out.effort[0] + rng.normal(0.0, std, n)
    column = EFFORT_COLUMNS[twin.effort_name][0]
    gain = 1.0 if current else (nominal.reference_gain or 1.0)
    columns = {
        "time_ms": t * 1e3,
        "x_cmd_mm": x_cmd * 1e3,
        "x_act_mm": out.x_m[0] * 1e3,
        column: effort / gain,
    }
    if out.voltage_q is not None:
        columns[VOLTAGE_COLUMN] = out.voltage_q[0]
    return columns


def position_spread(
    nominal: ModelDoc,
    hidden: Mapping[str, Mapping[str, float]],
    *,
    seeds: tuple[int, ...],
    unmodelled: Unmodelled | None = None,
    program: str = PROGRAM,
    nc_config: str = NC_CONFIG,
    start_m: float = 0.0,
) -> np.ndarray:
    """[m] per sample, the standard deviation of the recorded position over realisations of
    one truth that differ only in their noise (`seed` and `sensor_seed` both set to each of
    `seeds`): what of a record no deterministic twin can reproduce. Where the nut crosses its
    backlash or the table comes to rest, a current ADC's rounding and noise change when and how
    hard it strikes or sticks, and records of the same machine part by hundreds of nm."""
    if len(seeds) < 2:
        raise ValueError(f"seeds = {seeds!r}: a spread needs at least two realisations")
    um = unmodelled or Unmodelled()
    x = np.array(
        [
            generate(
                nominal,
                hidden,
                unmodelled=replace(um, seed=seed, sensor_seed=seed),
                program=program,
                nc_config=nc_config,
                start_m=start_m,
            )["x_act_mm"]
            * 1e-3
            for seed in seeds
        ]
    )
    return np.std(x, axis=0, ddof=1)


def _friction_growth(
    truth: ModelDoc, t: np.ndarray, v: np.ndarray, growth: float
) -> np.ndarray | None:
    """The force on the table [N] of a guide friction that grows by `growth` of itself over
    the record (at the commanded speed), None for none."""
    fr = truth.friction()
    if growth == 0.0 or fr is None:
        return None
    fields = ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg", "dF_s", "v_s", "v_reg")
    p = [truth.get(f"{fr}.{name}") for name in fields]
    force = np.array([friction_force(float(speed), *p) for speed in v])
    return -growth * (t - t[0]) / (t[-1] - t[0]) * force


def as_trace(columns: Mapping[str, np.ndarray], period_ticks: int) -> dict[str, np.ndarray]:
    """The columns of a record at the base period as a drive's trace records them: each the
    mean over the time of `period_ticks` ticks (recorder.period_mean, the value before the
    record held), one sample per period, stamped (time_ms) at the end of its window, as
    Twin.simulate takes a record whose map says `trace_filter: mean`."""
    if period_ticks < 1:
        raise ValueError(f"period_ticks = {period_ticks!r}: must be >= 1")
    n = len(columns["time_ms"]) // period_ticks * period_ticks
    out = {
        k: period_mean(np.concatenate((v[:1], v[:n])), period_ticks)[0, 1:]
        for k, v in columns.items()
    }
    out["time_ms"] = columns["time_ms"][period_ticks - 1 : n : period_ticks].copy()
    return out


def write_csv(path: str | Path, columns: Mapping[str, np.ndarray], nominal: ModelDoc) -> Path:
    """Write the record and its column map `<stem>_map.yaml` next to it; returns the map."""
    path = Path(path)
    names = list(columns)
    table = np.column_stack([columns[k] for k in names])
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.12g")
    map_path = path.with_name(f"{path.stem}_map.yaml")
    effort = next(k for k, (col, _) in EFFORT_COLUMNS.items() if col in columns)
    entry = EFFORT_COLUMNS[effort][1].format(gain=nominal.reference_gain or 1.0)
    sensor = "linear_scale" if nominal.of_type("LinearScale") else "motor_encoder"
    voltage = (
        f"\n  voltage_q_V: {{column: {VOLTAGE_COLUMN}, unit: V}}"
        if VOLTAGE_COLUMN in columns
        else ""
    )
    map_path.write_text(MAP.format(sensor=sensor, effort=entry, voltage=voltage))
    return map_path
