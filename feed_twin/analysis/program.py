"""The command of a record that has none, from the G-code program that ran.

Many drive scopes record only actual values. The program is planned with feed_twin.gcode
(`plan_program`, the NC section of the model or, failing that, of config/axis_default.yaml) and
its axis setpoints are placed on the record's clock: the time offset is the shift that best
aligns the planned velocity with the measured one (cross-correlation over the whole record,
refined below one sample, see analysis.compare), and the position offset is the median
difference after the shift (a different encoder zero). Because an axis follows its command
late, the estimate is refined (twice) with the nominal twin's response to the placed command. Both
numbers are reported as a warning of the run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.analysis.compare import align
from feed_twin.io.config import load_yaml
from feed_twin.io.measured import MeasuredDataError, MeasuredRun

REFINEMENTS = 2  # alignments against the twin's response
DEFAULT_NC = Path(__file__).resolve().parents[2] / "config" / "axis_default.yaml"


def _nc_config(nc: dict[str, Any] | None, source: str):
    from feed_twin.gcode.config import nc_config_from_mapping

    if nc is None:
        data = load_yaml(DEFAULT_NC)
        return nc_config_from_mapping(data["nc"], source=str(DEFAULT_NC))
    return nc_config_from_mapping(nc, source=source)


def command_from_program(
    run: MeasuredRun,
    program: str | Path,
    *,
    nc: dict[str, Any] | None = None,
    nc_source: str = "<nc>",
    model: Any = None,
) -> MeasuredRun:
    """`run` with pos_cmd_m and vel_cmd_m_s from the planned program, aligned to its clock.

    With `model` (an analysis.twin.ModelDoc) the alignment is refined twice against the twin's
    simulated response instead of the bare command.
    """
    from feed_twin.gcode.planner import plan_program

    if "pos_meas_m" not in run:
        raise MeasuredDataError(
            f"{run.source}: aligning a program needs the measured position pos_meas_m"
        )
    cfg = _nc_config(nc, nc_source)
    traj = plan_program(program, cfg)
    x_prog, v_prog, _ = traj.axis(cfg.twin_axis)
    t_prog = traj.t_s - traj.t_s[0]
    t = run.t_s
    x = run["pos_meas_m"]
    # place the program on a grid that covers the record whatever the offset: pad both ends
    # with the program's first and last setpoints (the axis stands still before and after)
    h = run.sample_period_s
    span = max(t[-1] - t[0], t_prog[-1])
    grid = t[0] - span + h * np.arange(int(np.ceil(3 * span / h)) + 1)
    x_grid = np.interp(grid - t[0], t_prog, x_prog)
    x_meas_grid = np.interp(grid, t, x, left=x[0], right=x[-1])
    a = align(grid, x_meas_grid, x_grid, max_shift_s=span)
    shift, offset = a.time_shift_s, a.position_offset_m
    if a.correlation < 0.5:
        raise MeasuredDataError(
            f"{run.source}: the program {program} does not match the measured motion "
            f"(best correlation {a.correlation:.2f} at a shift of {shift:.3f} s)"
        )
    pos = np.interp(t - t[0] - shift, t_prog, x_prog) + offset
    vel = np.interp(t - t[0] - shift, t_prog, v_prog)
    if model is not None:
        # the measured axis follows its command late (a P position loop lags by about 1/Kv):
        # compare the twin's response, not the command, with the measurement
        from feed_twin.analysis.twin import Twin, drive_from_run

        twin = Twin.compile(model)
        # twice: the twin starts from the record's measured state, and a command still a few
        # milliseconds off (the bare estimate) upsets its first samples, which moves the
        # second estimate by a tenth of a millisecond
        for _ in range(REFINEMENTS):
            trial = run.with_signals(pos_cmd_m=pos, vel_cmd_m_s=vel)
            sim = twin.simulate(drive_from_run(trial), twin.nominal[None, :])
            if not sim.ok[0]:
                break
            b = align(t, x, sim.x_m[0], max_shift_s=0.05)
            shift += b.time_shift_s
            offset += b.position_offset_m
            pos = np.interp(t - t[0] - shift, t_prog, x_prog) + offset
            vel = np.interp(t - t[0] - shift, t_prog, v_prog)
    note = (
        f"command from {program}: the program starts {shift:+.4f} s after the record "
        f"(correlation {a.correlation:.4f}), position offset {offset * 1e6:+.2f} um"
    )
    out = run.with_signals(pos_cmd_m=pos, vel_cmd_m_s=vel)
    return MeasuredRun(
        source=out.source,
        t_s=out.t_s,
        signals=out.signals,
        position_sensor=out.position_sensor,
        warnings=out.warnings + (note,),
    )
