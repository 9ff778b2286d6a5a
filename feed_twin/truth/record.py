"""A truth-machine record on disk: program -> machine -> trace -> CSV + column map.

The commanded trajectory comes from feed_twin.gcode's planner (the NC's 1 ms setpoints, as a
real NC sends them); the drive fine-interpolates them (feed_twin.truth.machine). The machine
holds its start position for `SETTLE_S` before the program (so the record starts settled, a
vertical axis' weight already carried) and the record covers the program plus `TAIL_S`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from feed_twin.truth.effects import machine_with
from feed_twin.truth.kernel import CHANNELS, kernel_params, run
from feed_twin.truth.machine import NOMINAL, Machine
from feed_twin.truth.trace import Trace, quantise, sample

SETTLE_S = 0.3  # [s] held at the start position before the program (not recorded)
TAIL_S = 0.3  # [s] recorded after the program's end
START_M = 0.2  # [m] table position at the program's X0

# Moves of several lengths and feeds in both directions, slow moves (Stribeck, stiction),
# reversals and dwells (held forces), over 0.3 m of the 0.8 m travel. About 7 s.
PROGRAM = """\
(feed_twin truth machine: moves and reversals along X)
G21 G90 G94 G54 G64
G1 X60 F9000
G4 P0.2
G1 X20 F4800
G1 X150 F12000
G4 P0.15
G1 X145 F300
G1 X90 F6000
G1 X92 F120
G4 P0.2
G1 X300 F10800
G1 X200 F2400
G4 P0.1
G1 X230 F900
G1 X0 F12000
G4 P0.2
M30
"""

# A second program (validation): other lengths, feeds and reversal points. About 6 s.
VALIDATION_PROGRAM = """\
(feed_twin truth machine: validation moves)
G21 G90 G94 G54 G64
G1 X120 F7200
G4 P0.1
G1 X40 F10800
G1 X45 F600
G1 X260 F9000
G4 P0.2
G1 X180 F3600
G1 X6 F12000
G4 P0.1
G1 X0 F240
G4 P0.2
M30
"""


def long_program(repeats: int) -> str:
    """PROGRAM's and VALIDATION_PROGRAM's moves one after the other, `repeats` times (about
    21 s each time): a record long enough at a shop-floor logger's 10 Hz."""
    if repeats < 1:
        raise ValueError(f"repeats = {repeats!r}: must be >= 1")

    def body(program: str) -> str:
        return "".join(
            line + "\n" for line in program.splitlines()[2:] if line.strip() and line != "M30"
        )

    header = "(feed_twin truth machine: long program)\nG21 G90 G94 G54 G64\n"
    return header + (body(PROGRAM) + body(VALIDATION_PROGRAM)) * repeats + "M30\n"


def nc_config(*, v_max: float, a_max: float, j_max: float, travel: float) -> str:
    """The NC section (feed_twin.gcode) of a three-axis machine whose axes move alike."""
    axes = "".join(
        f"    - {{name: {n}, v_max_m_s: {v_max}, rapid_m_s: {v_max}, a_max_m_s2: {a_max}, "
        f"j_max_m_s3: {j_max}, travel_min_m: -0.01, travel_max_m: {travel}}}\n"
        for n in "XYZ"
    )
    offsets = "".join(f"    G{g}: [0.0, 0.0, 0.0]\n" for g in range(54, 60))
    return (
        "nc:\n  twin_axis: X\n  profile: jerk\n  interpolation_period_s: 0.001\n"
        "  path_tolerance_m: 1.0e-5\n  chord_tolerance_m: 2.0e-6\n"
        "  arc_radius_tolerance_m: 1.0e-5\n  lookahead_segments: 200\n  block_delete: true\n"
        "  dwell_p_unit: s\n  start_position_m: [0.0, 0.0, 0.0]\n"
        f"  axes:\n{axes}  work_offsets_m:\n{offsets}"
    )


# the truth machine's NC: 0.2 m/s, 2 m/s^2, 60 m/s^3
NC_CONFIG = nc_config(v_max=0.2, a_max=2.0, j_max=60.0, travel=0.6)


def command(program: str = PROGRAM, nc_config: str = NC_CONFIG) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], X setpoint [m]) of a G-code program planned by feed_twin.gcode, 1 ms apart."""
    import yaml

    from feed_twin.gcode.config import nc_config_from_mapping
    from feed_twin.gcode.planner import plan_program

    cfg = nc_config_from_mapping(yaml.safe_load(nc_config)["nc"], source="<truth nc>")
    traj = plan_program(program, cfg)
    x, _, _ = traj.axis("X")
    return traj.t_s.copy(), x.copy()


@dataclass(frozen=True)
class Run:
    """The machine's signals once per current period: t_s[k] ends period k."""

    fast_s: float
    t_s: np.ndarray
    # the NC's setpoint at each period's end (its path between NC points: linear), so that a
    # trace sampling at an NC stamp records the NC point itself. Taken at the period's start,
    # as the drive holds it over the period, a 1 kHz trace recorded every NC point one current
    # period (0.125 ms) stale: the machine then followed its recorded command 0.125 ms early,
    # a 13 um position residual on every record (a setpoint latency no machine effect had)
    x_cmd_m: np.ndarray
    signals: dict[str, np.ndarray]  # CHANNELS


def simulate(machine: Machine, t_nc: np.ndarray, x_nc: np.ndarray) -> Run:
    """Run the machine on an NC setpoint sequence (t_nc from 0, uniform), from rest at x_nc[0]
    held for SETTLE_S, through TAIL_S after the last setpoint. Times from the program's start."""
    fast = 1.0 / machine.f_current_hz
    n_settle = round(SETTLE_S / fast)
    n = round((t_nc[-1] + TAIL_S) / fast)
    t_fast = (np.arange(-n_settle, n)) * fast  # period starts
    # the drive's fine interpolation: a cubic Hermite spline through the NC points (speeds by
    # central differences), setpoint_latency_s late, held outside. Linear interpolation would
    # step the speed feed-forward once per NC period, and the current would kick at each step:
    # a trace sampling at the NC rate sees those kicks at one phase, a bias in proportion to
    # the acceleration (a mass error of 2 % on this axis)
    spline = CubicHermiteSpline(t_nc, x_nc, np.gradient(x_nc, t_nc))
    tt = np.clip(t_fast - machine.setpoint_latency_s, t_nc[0], t_nc[-1])
    x_ref = spline(tt)
    v_ref = spline(tt, 1)
    out = run(kernel_params(machine), x_ref, v_ref, float(x_nc[0]))
    if not np.all(np.isfinite(out)):
        raise RuntimeError("the truth machine diverged (check its parameters)")
    keep = slice(n_settle, None)
    ends = t_fast[keep] + fast
    return Run(
        fast_s=fast,
        t_s=ends,
        x_cmd_m=np.interp(ends, t_nc, x_nc),
        signals={name: out[keep, i] for i, name in enumerate(CHANNELS)},
    )


def trace_columns(
    run_: Run, machine: Machine, trace: Trace, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """The record's columns in the file's units (ms, mm, A or N m), as the trace exports them."""
    n = int(np.floor(run_.t_s[-1] / trace.period_s + 1e-9))
    t = np.arange(1, n + 1) * trace.period_s
    window = trace.period_s if trace.average else 0.0
    pos_name = "x_table_m" if trace.position_source == "scale" else "x_motor_m"

    def seen(y: np.ndarray, delay: float) -> np.ndarray:
        return sample(y, run_.fast_s, t, delay_s=delay, window_s=window)

    x_cmd = quantise(seen(run_.x_cmd_m, trace.delay_command_s), trace.command_resolution_m)
    x_act = quantise(
        seen(run_.signals[pos_name], trace.delay_position_s), trace.position_resolution_m
    )
    source = "i_q_meas_A" if trace.effort_source == "actual" else "i_q_ref_A"
    current = seen(run_.signals[source], trace.delay_effort_s)
    current = (
        current + rng.normal(0.0, trace.effort_noise_A, len(t)) if trace.effort_noise_A else current
    )
    current = quantise(current, trace.effort_resolution_A) * trace.effort_sign
    columns = {"time_ms": t * 1e3, "x_cmd_mm": x_cmd * 1e3, "x_act_mm": x_act * 1e3}
    if trace.effort_unit == "A":
        columns["i_q_A"] = current
    else:
        columns["torque_Nm"] = current * NOMINAL.K_t
    return columns


def write(path: str | Path, columns: Mapping[str, np.ndarray], trace: Trace) -> Path:
    """Write the CSV and its column map `<stem>_map.yaml` next to it; returns the map's path."""
    path = Path(path)
    rows = np.column_stack(list(columns.values()))
    with path.open("w") as out:
        out.write(",".join(columns) + "\n")
        np.savetxt(out, rows, delimiter=",", fmt="%.10g")
    import yaml

    effort: dict[str, object] = (
        {"column": "i_q_A", "unit": "A", "gain": NOMINAL.K_t}
        if "i_q_A" in columns
        else {"column": "torque_Nm", "unit": "Nm"}
    )
    column_map: dict[str, object] = {
        "time": {"column": "time_ms", "unit": "ms"},
        "position_sensor": "linear_scale" if trace.position_source == "scale" else "motor_encoder",
        "signals": {
            "pos_cmd_m": {"column": "x_cmd_mm", "unit": "mm"},
            "pos_meas_m": {"column": "x_act_mm", "unit": "mm"},
            "torque_cmd_Nm": effort,
        },
        "plausibility": {"travel_m": 1.0, "max_speed_m_s": 0.5},
    }
    if trace.effort_source == "setpoint":
        column_map["effort_sample"] = "setpoint"  # the drive's current setpoint, not its actual
    if trace.average and trace.declare_average:
        column_map["trace_filter"] = "mean"
    map_path = path.with_name(f"{path.stem}_map.yaml")
    header = "# column map of a truth-machine record (feed_twin.truth)\n"
    map_path.write_text(header + yaml.safe_dump(column_map, sort_keys=False))
    return map_path


@dataclass(frozen=True)
class Record:
    csv: Path
    map: Path
    machine: Machine  # the truth, effects set
    hidden: dict[str, dict[str, float]]


def make_record(
    path: str | Path,
    *,
    hidden: Mapping[str, Mapping[str, float]] | None = None,
    machine: Machine = NOMINAL,
    trace: Trace | None = None,
    program: str = PROGRAM,
    nc_config: str = NC_CONFIG,
    seed: int = 0,
) -> Record:
    """Simulate `machine` with `hidden` effects on `program` and write what `trace` records to
    `path` (CSV) and its column map; `seed` draws the measurement noise."""
    hidden = {k: dict(v) for k, v in (hidden or {}).items()}
    truth = machine_with(hidden, machine)
    t_nc, x_nc = command(program, nc_config)
    run_ = simulate(truth, t_nc, x_nc + START_M)
    tr = trace or Trace()
    columns = trace_columns(run_, truth, tr, np.random.default_rng(seed))
    map_path = write(path, columns, tr)
    return Record(csv=Path(path), map=map_path, machine=truth, hidden=hidden)
