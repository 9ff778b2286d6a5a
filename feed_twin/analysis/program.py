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
# [s] block shifts that spread less than this are one shift for all: the loop's lag differs by
# milliseconds from move to move, an NC's waits between blocks are tens of milliseconds
WARP_MIN_SPREAD_S = 0.015
BLOCK_SEARCH_S = (-0.05, 0.3)  # [s] a block's start against the previous block's shift
FIRST_BLOCK_SEARCH_S = (-1.0, 1.0)  # [s] the first block's against the whole program's
LOCAL_SEARCH_S = 0.01  # [s] a block's correction against the twin's response
REST_SHARE = 1e-3  # below this share of the peak speed the program rests
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
    # block by block where the NC's own waits between blocks (exact stop and settle) moved
    # the blocks apart: each move at its own shift, found on the velocities (offset-free)
    moves = _moves(t_prog, v_prog)
    v_meas = np.gradient(x, h)
    shifts = _block_shifts(t - t[0], v_meas, t_prog, v_prog, moves, shift)
    warp = shifts is not None and float(np.ptp(shifts)) > WARP_MIN_SPREAD_S

    def placed(delta: float) -> tuple[np.ndarray, np.ndarray]:
        """The program on the record's clock, delta [s] later than the estimate, no offset."""
        if warp:
            assert shifts is not None
            return _warped(t - t[0], t_prog, x_prog, v_prog, moves, shifts + delta)
        return (
            np.interp(t - t[0] - shift - delta, t_prog, x_prog),
            np.interp(t - t[0] - shift - delta, t_prog, v_prog),
        )

    delta = 0.0
    pos, vel = placed(delta)
    if warp:
        offset = float(np.median(x - pos))
    pos = pos + offset
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
            if warp:
                # each block against the twin's response to it: the loop's lag differs from
                # move to move, which the bare comparison of velocities left in the shifts
                assert shifts is not None
                v_sim = np.gradient(sim.x_m[0], h)
                for i, (start, end) in enumerate(moves):
                    lo, hi = start + shifts[i] + delta, end + shifts[i] + delta
                    shifts[i] += _local_shift(t - t[0], v_meas, v_sim, lo, hi)
                offset += float(np.median(x - sim.x_m[0]))
            else:
                b = align(t, x, sim.x_m[0], max_shift_s=0.05)
                delta += b.time_shift_s
                offset += b.position_offset_m
            pos, vel = placed(delta)
            pos = pos + offset
    shift += delta
    note = (
        f"command from {program}: the program starts {shift:+.4f} s after the record "
        f"(correlation {a.correlation:.4f}), position offset {offset * 1e6:+.2f} um"
    )
    if warp:
        assert shifts is not None
        late = 1e3 * (shifts - shifts[0])
        note += (
            f"; aligned block by block: {len(moves)} moves, the last {late[-1]:+.1f} ms later "
            "than the first would be by the program (the NC's own waits between blocks, e.g. "
            f"exact stop and settle; a median {float(np.median(np.diff(late))):.0f} ms per "
            "block: nc.exact_stop_settle_s plans such a wait after G60/G61/G9 blocks)"
        )
    out = run.with_signals(pos_cmd_m=pos, vel_cmd_m_s=vel)
    return MeasuredRun(
        source=out.source,
        t_s=out.t_s,
        signals=out.signals,
        position_sensor=out.position_sensor,
        warnings=out.warnings + (note,),
    )


def _moves(t_prog: np.ndarray, v_prog: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) [s] of the program's moves: where it does not rest."""
    moving = np.abs(v_prog) > REST_SHARE * float(np.max(np.abs(v_prog)))
    edges = np.flatnonzero(np.diff(np.r_[0, moving.astype(int), 0]))
    return [
        (float(t_prog[a]), float(t_prog[b - 1]))
        for a, b in zip(edges[::2], edges[1::2], strict=True)
    ]


def _block_shifts(
    t: np.ndarray,
    v: np.ndarray,
    t_prog: np.ndarray,
    v_prog: np.ndarray,
    moves: list[tuple[float, float]],
    shift: float,
) -> np.ndarray | None:
    """Each move's own shift [s] (record time = program time + shift_i): the one that best lays
    the planned velocity of the move over the measured velocity, searched from the previous
    move's shift (an NC delays a block by its exact stop and settle time, never by much less),
    to a fraction of a sample by a parabola through the best three."""
    if len(moves) < 2:
        return None
    h = float(t[1] - t[0])
    shifts = []
    previous = shift
    for i, (start, end) in enumerate(moves):
        tau = np.arange(start, end + h, h)
        target = np.interp(tau, t_prog, v_prog)
        # the first block is searched widely: the whole program's shift is off by the waits
        lo, hi = FIRST_BLOCK_SEARCH_S if i == 0 else BLOCK_SEARCH_S
        trials = previous + np.arange(lo, hi + h, h)
        cost = np.array([np.mean((np.interp(tau + s, t, v) - target) ** 2) for s in trials])
        k = int(np.argmin(cost))
        best = float(trials[k])
        if 0 < k < len(trials) - 1:
            c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
            curvature = c0 - 2.0 * c1 + c2
            if curvature > 0:
                best += 0.5 * h * (c0 - c2) / curvature
        shifts.append(best)
        previous = best
    return np.asarray(shifts)


def _warped(
    t: np.ndarray,
    t_prog: np.ndarray,
    x_prog: np.ndarray,
    v_prog: np.ndarray,
    moves: list[tuple[float, float]],
    shifts: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The program on the record's clock with each move at its own shift; between moves the
    setpoint holds where the last move ended (a later move never starts before the last ends)."""
    pos = np.full_like(t, float(x_prog[0]))
    vel = np.zeros_like(t)
    ends = [s + e for (_, e), s in zip(moves, shifts, strict=True)]
    for i, ((start, end), s) in enumerate(zip(moves, shifts, strict=True)):
        begin = max(start + s, ends[i - 1] if i else -np.inf)
        inside = (t >= begin) & (t <= end + s)
        pos[inside] = np.interp(t[inside] - s, t_prog, x_prog)
        vel[inside] = np.interp(t[inside] - s, t_prog, v_prog)
        after = t > end + s
        pos[after] = float(np.interp(end, t_prog, x_prog))
        vel[after] = 0.0
    return pos, vel


def _local_shift(t: np.ndarray, v: np.ndarray, v_sim: np.ndarray, t0: float, t1: float) -> float:
    """The shift s [s] within +/-LOCAL_SEARCH_S that best lays v_sim(t - s) over v(t) on
    [t0, t1], to a fraction of a sample (parabola through the best three)."""
    h = float(t[1] - t[0])
    inside = (t >= t0) & (t <= t1)
    if inside.sum() < 3:
        return 0.0
    trials = np.arange(-LOCAL_SEARCH_S, LOCAL_SEARCH_S + h / 2, h)
    cost = np.array(
        [np.mean((v[inside] - np.interp(t[inside] - s, t, v_sim)) ** 2) for s in trials]
    )
    k = int(np.argmin(cost))
    best = float(trials[k])
    if 0 < k < len(trials) - 1:
        curvature = cost[k - 1] - 2.0 * cost[k] + cost[k + 1]
        if curvature > 0:
            best += 0.5 * h * (cost[k - 1] - cost[k + 1]) / curvature
    return best
