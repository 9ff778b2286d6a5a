"""The command of a record that has none, from the G-code program that ran.

Many drive scopes record only actual values. The program is planned with feed_twin.gcode
(`plan_program`, the NC section of the model: there is no default NC, because another machine's
axis limits, start position, work offsets and exact-stop settle would place the program
millimetres and tens of milliseconds off without a word) and
its axis setpoints are placed on the record's clock: the time offset is the shift that best
aligns the planned velocity with the measured one (cross-correlation over the whole record,
refined below one sample, see analysis.compare), and the position offset is the median
difference after the shift (a different encoder zero). Because an axis follows its command
late (by about 1/Kv: 40-60 ms on a machine tool), the estimate is refined (REFINEMENTS times)
with the nominal twin's response to the placed command, the whole program first, then block by
block. Both
numbers are reported as a warning of the run. The placed program is kept at the NC's own period
too (`MeasuredRun.plan`), which the twin interpolates onto its base ticks.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.analysis.compare import align
from feed_twin.io.measured import MeasuredDataError, MeasuredRun, PlannedCommand

REFINEMENTS = 3  # alignments against the twin's response
GLOBAL_SEARCH_S = 0.1  # [s] the whole program's correction against the twin's response
# [s] block shifts that spread less than this are one shift for all: the loop's lag differs by
# milliseconds from move to move, an NC's waits between blocks are tens of milliseconds
WARP_MIN_SPREAD_S = 0.015
BLOCK_SEARCH_S = (-0.05, 0.3)  # [s] a block's start against the previous block's shift
FIRST_BLOCK_SEARCH_S = (-1.0, 1.0)  # [s] the first block's against the whole program's
LOCAL_SEARCH_S = 0.01  # [s] a block's correction against the twin's response
LOCAL_STEP_S = 0.001  # [s] the steps of that search on a trace slower than 1 kHz
REST_SHARE = 1e-3  # below this share of the peak speed the program rests
# above this share of its peak speed a trace moves (a measured speed's noise stays below it)
MOVING_SHARE = 0.05
# the record moving this many times as long as the placed program: the program ran more often
UNCOVERED_RATIO = 1.5
# below this share of the peak speed both the record and the placed program rest, and there
# the placed position must meet the measured one within MISS_TOLERANCE_M (an axis at rest
# follows its command within micrometres; a program placed on the wrong record misses by
# millimetres: 103 mm on a real record, which was only a warning)
AT_REST_SHARE = 2e-3
MISS_TOLERANCE_M = 1e-3


def nc_of_model(data: dict[str, Any], source: str) -> dict[str, Any]:
    """The model's `nc:` section, which planning a program needs."""
    nc = data.get("nc")
    if not isinstance(nc, dict):
        raise MeasuredDataError(
            f"{source}: --program needs the model's nc: section (the NC the program ran on: "
            "axis limits, start position, work offsets, exact-stop settle); copy the nc: section "
            "of config/axis_default.yaml and set it to the machine's"
        )
    return nc


def command_from_program(
    run: MeasuredRun,
    program: str | Path,
    *,
    nc: dict[str, Any],
    nc_source: str = "<nc>",
    model: Any = None,
) -> MeasuredRun:
    """`run` with pos_cmd_m and vel_cmd_m_s from the planned program, aligned to its clock,
    and the same command at the NC's interpolation period as `run.plan` (what the twin is
    driven with: a 50 Hz trace's samples miss each stop's final approach, and with it the
    side on which friction holds the table).

    With `model` (an analysis.twin.ModelDoc) the alignment is refined twice against the twin's
    simulated response instead of the bare command.
    """
    from feed_twin.gcode.config import nc_config_from_mapping
    from feed_twin.gcode.planner import plan_program

    if "pos_meas_m" not in run:
        raise MeasuredDataError(
            f"{run.source}: aligning a program needs the measured position pos_meas_m"
        )
    cfg = nc_config_from_mapping(nc, source=nc_source)
    traj = plan_program(program, cfg)
    x_prog, v_prog, a_prog = traj.axis(cfg.twin_axis)
    t_prog = traj.t_s - traj.t_s[0]
    rows = (x_prog, v_prog, a_prog)
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
        why = f"does not match the measured motion (best correlation {a.correlation:.2f} at a "
        raise _unplaced(run, program, why + f"shift of {shift:.3f} s)")
    # block by block where the NC's own waits between blocks (exact stop and settle) moved
    # the blocks apart: each move at its own shift, found on the velocities (offset-free)
    moves = _moves(t_prog, v_prog)
    v_meas = np.gradient(x, h)
    shifts = _block_shifts(t - t[0], v_meas, t_prog, v_prog, moves, shift)
    warp = shifts is not None and float(np.ptp(shifts)) > WARP_MIN_SPREAD_S

    # the NC's own period over the record: the twin is driven from these setpoints, which a
    # trace slower than the NC samples too coarsely (MeasuredRun.plan)
    h_nc = float(t_prog[1] - t_prog[0])
    t_nc = t[0] + h_nc * np.arange(int(np.ceil((t[-1] - t[0]) / h_nc)) + 1)

    def placed(delta: float, times: np.ndarray) -> np.ndarray:
        """(position, velocity, acceleration) of the program at `times` on the record's clock,
        delta [s] later than the estimate, no offset."""
        if warp:
            assert shifts is not None
            return _warped(times - t[0], t_prog, rows, moves, shifts + delta)
        return np.array([np.interp(times - t[0] - shift - delta, t_prog, y) for y in rows])

    def commanded(delta: float, offset: float) -> MeasuredRun:
        pos, vel, _ = placed(delta, t)
        fine = placed(delta, t_nc)
        plan = PlannedCommand(t_s=t_nc, pos_m=fine[0] + offset, vel_m_s=fine[1], acc_m_s2=fine[2])
        return dataclasses.replace(
            run.with_signals(pos_cmd_m=pos + offset, vel_cmd_m_s=vel),
            plan=plan,
            position_offset_free=True,
        )

    _check_covered(run, program, t, v_meas, placed(0.0, t)[1])
    delta = 0.0
    if warp:
        offset = float(np.median(x - placed(delta, t)[0]))
    trial = commanded(delta, offset)
    if model is not None:
        # the measured axis follows its command late (a P position loop lags by about 1/Kv):
        # compare the twin's response, not the command, with the measurement
        from feed_twin.analysis.twin import Twin, drive_from_run

        twin = Twin.compile(model)
        # more than once: the twin starts from the record's measured state, and a command
        # still a few milliseconds off (the bare estimate) upsets its first samples, which
        # moves the next estimate by a tenth of a millisecond
        for _ in range(REFINEMENTS):
            sim = twin.simulate(drive_from_run(trial), twin.nominal[None, :])
            if not sim.ok[0]:
                break
            # the whole program against the twin's response first: the loop's lag (1/Kv, 40
            # to 60 ms on a machine tool's axis) is common to every block, and a block's own
            # search below reaches LOCAL_SEARCH_S only (the twin stayed 28-38 ms behind)
            b = align(t, x, sim.x_m[0], max_shift_s=GLOBAL_SEARCH_S)
            delta += b.time_shift_s
            offset += b.position_offset_m
            trial = commanded(delta, offset)
            if warp:
                assert shifts is not None
                offset = _refine_blocks(
                    twin, trial, commanded, shifts=shifts, moves=moves, delta=delta, offset=offset
                )
                trial = commanded(delta, offset)
    shift += delta
    _check_fit(run, program, trial, len(moves))
    note = _placement_note(program, shift, a.correlation, offset, moves, shifts if warp else None)
    return dataclasses.replace(trial, warnings=trial.warnings + (note,))


def _refine_blocks(
    twin: Any,
    trial: MeasuredRun,
    commanded: Any,
    *,
    shifts: np.ndarray,
    moves: list[tuple[float, float]],
    delta: float,
    offset: float,
) -> float:
    """Each block's shift (in place) against the twin's response to it: the loop's lag differs
    from move to move, which the bare comparison of velocities left in the shifts. Returns the
    position zero read again against the response to the moved blocks: read off the response
    to the blocks before, it took each block's time error for a position error (+96, then
    -100 um on a 50 Hz exact-stop trace, never settling)."""
    from feed_twin.analysis.twin import drive_from_run

    t, x, h = trial.t_s, trial["pos_meas_m"], trial.sample_period_s
    sim = twin.simulate(drive_from_run(trial), twin.nominal[None, :])
    if not sim.ok[0]:
        return offset
    v_meas, v_sim = np.gradient(x, h), np.gradient(sim.x_m[0], h)
    for i, (start, end) in enumerate(moves):
        lo, hi = start + shifts[i] + delta, end + shifts[i] + delta
        shifts[i] += _local_shift(t - t[0], v_meas, v_sim, lo, hi)
    sim = twin.simulate(drive_from_run(commanded(delta, offset)), twin.nominal[None, :])
    if not sim.ok[0]:
        return offset
    return offset + float(np.median(x - sim.x_m[0]))


def _placement_note(
    program: str | Path,
    shift: float,
    correlation: float,
    offset: float,
    moves: list[tuple[float, float]],
    shifts: np.ndarray | None,
) -> str:
    """The run's warning that says where the program was placed (`shifts`: block by block)."""
    note = (
        f"command from {program}: the program starts {shift:+.4f} s after the record "
        f"(correlation {correlation:.4f}), position offset {offset * 1e6:+.2f} um"
    )
    if shifts is None:
        return note
    late = 1e3 * (shifts - shifts[0])
    return note + (
        f"; aligned block by block: {len(moves)} moves, the last {late[-1]:+.1f} ms later "
        "than the first would be by the program (the NC's own waits between blocks, e.g. "
        f"exact stop and settle; a median {float(np.median(np.diff(late))):.0f} ms per "
        "block: nc.exact_stop_settle_s plans such a wait after G60/G61/G9 blocks)"
    )


def _check_covered(
    run: MeasuredRun, program: str | Path, t: np.ndarray, v_meas: np.ndarray, v_cmd: np.ndarray
) -> None:
    """The placed program must account for the record's motion: one run of a program that the
    record holds three times correlates well enough with one of them, and the twin would then
    be driven to stand still through the others."""
    h = float(t[1] - t[0])
    moving = float(np.sum(np.abs(v_meas) > MOVING_SHARE * np.max(np.abs(v_meas)))) * h
    commanded = float(np.sum(np.abs(v_cmd) > MOVING_SHARE * np.max(np.abs(v_cmd)))) * h
    if moving > UNCOVERED_RATIO * commanded:
        why = f"moves the axis for {commanded:.3g} s, the record moves for {moving:.3g} s"
        raise _unplaced(run, program, why)


def _check_fit(run: MeasuredRun, program: str | Path, placed: MeasuredRun, moves: int) -> None:
    """Refuse, in one line, a placed program whose rests miss the record's by more than
    MISS_TOLERANCE_M (see AT_REST_SHARE)."""
    x, cmd = run["pos_meas_m"], placed["pos_cmd_m"]
    v_meas = np.abs(np.gradient(x, run.sample_period_s))
    v_cmd = np.abs(placed["vel_cmd_m_s"])
    rest = (v_meas <= AT_REST_SHARE * v_meas.max()) & (v_cmd <= AT_REST_SHARE * v_cmd.max())
    if not rest.any():
        return
    miss = np.where(rest, np.abs(x - cmd), 0.0)
    worst = int(np.argmax(miss))
    if miss[worst] <= MISS_TOLERANCE_M:
        return
    raise MeasuredDataError(
        f"{run.source}: the program {program} does not fit the record: placed ({moves} moves), "
        f"it rests {miss[worst] * 1e3:.3g} mm away from where the axis rests at "
        f"t = {run.t_s[worst]:.3f} s (at most {MISS_TOLERANCE_M * 1e3:g} mm fit); check that "
        "the program, the model's nc: section (start position, work offsets) and the record's "
        "axis belong together"
    )


def _unplaced(run: MeasuredRun, program: str | Path, why: str) -> MeasuredDataError:
    return MeasuredDataError(
        f"{run.source}: the program {program} {why}; if the record holds the program several "
        "times, add --repetitions or cut one run with --segment t0:t1"
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
    rows: tuple[np.ndarray, ...],
    moves: list[tuple[float, float]],
    shifts: np.ndarray,
) -> np.ndarray:
    """The program's rows (a position, then its rates) on the record's clock with each move at
    its own shift; between moves the position holds where the last move ended and the rates
    are zero (a later move never starts before the last ends)."""
    out = np.zeros((len(rows), len(t)))
    out[0] = rows[0][0]
    ends = [s + e for (_, e), s in zip(moves, shifts, strict=True)]
    for i, ((start, end), s) in enumerate(zip(moves, shifts, strict=True)):
        begin = max(start + s, ends[i - 1] if i else -np.inf)
        inside = (t >= begin) & (t <= end + s)
        for row, y in zip(out, rows, strict=True):
            row[inside] = np.interp(t[inside] - s, t_prog, y)
        after = t > end + s
        out[0, after] = float(np.interp(end, t_prog, rows[0]))
        out[1:, after] = 0.0
    return out


def _local_shift(t: np.ndarray, v: np.ndarray, v_sim: np.ndarray, t0: float, t1: float) -> float:
    """The shift s [s] within +/-LOCAL_SEARCH_S that best lays v_sim(t - s) over v(t) on
    [t0, t1], tried every LOCAL_STEP_S (or every sample, if closer) and refined to a fraction
    of a step by a parabola through the best three. v_sim is shifted by a cubic spline: a
    50 Hz trace's samples are 20 ms apart, twice the search, and a straight line between them
    pulls the shift towards whole samples."""
    from scipy.interpolate import CubicSpline

    h = float(t[1] - t[0])
    step = min(h, LOCAL_STEP_S)
    inside = (t >= t0) & (t <= t1)
    if inside.sum() < 3:
        return 0.0
    spline = CubicSpline(t, v_sim)
    trials = np.arange(-LOCAL_SEARCH_S, LOCAL_SEARCH_S + step / 2, step)
    cost = np.array(
        [np.mean((v[inside] - spline(np.clip(t[inside] - s, t[0], t[-1]))) ** 2) for s in trials]
    )
    k = int(np.argmin(cost))
    best = float(trials[k])
    if 0 < k < len(trials) - 1:
        curvature = cost[k - 1] - 2.0 * cost[k] + cost[k + 1]
        if curvature > 0:
            best += 0.5 * step * (cost[k - 1] - cost[k + 1]) / curvature
    return best
