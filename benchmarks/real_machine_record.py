"""A record made the way real machines make them, and the discrepancy workflow on it.

The generator (analysis.synthetic's truth engine, then what a machine's trace does to it):
- a vertical axis: the EMPS twin with the table's weight (a constant force of -120 N) and a
  friction that holds the table at rest (stiction, F_hold = 20 N, which slides as Coulomb
  friction), plus the truth's unmodelled current-loop lag, softer coupling and effort noise;
- the NC program three times in one record, with rests of 0.3 s and 0.5 s between the runs,
  every block an exact stop (G61) after which the NC waits 65 ms for the in-position window
  before the next (per-block NC delays, 1.7 s over the record);
- the drive's current as the effort, in amperes (force constant 35.15 N/A), counted against
  the motion (the opposite sign), and stamped 4 ms after the position (a trace-side delay);
- every channel averaged over 20 ms (the drive's trace filter) and sampled at 50 Hz;
- no commanded position: the trace holds the actual position and the current only.

The workflow gets the CSV, a column map (which says the trace averages, `trace_filter: mean`,
so the twin's outputs are averaged the same way) and the program as the user has it (the NC's
waits are not in it, nor in the NC configuration it is planned with): `diagnose --program`'s
path, analysis.program.command_from_program, places it block by block and drives the twin with
it at the NC's 1 kHz period. With the current's sign as recorded it must stop with the one-line
reversed-sign error; with the sign declared (a negative force constant) it finds the
repetitions, identifies on the first run and validates on the second.
The figures: the effects named, and the current error after the fit against a
least-squares fit of the same effects by hand (constant force, sliding friction sign(v), the
force held at rest, and the channel delay as the rate of the nominal twin's effort, added to
the nominal twin's effort) on the same run, over all its samples and over those that are
evidence (from Twin.first_evidence on; the first samples average the window before the twin's
start and dominate both RMS values over all samples). Last printed line: one JSON object.

    .venv/bin/python benchmarks/real_machine_record.py
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from feed_twin.analysis.diagnose import check_effort_sign
from feed_twin.analysis.effects import last_direction, motion_from_position, moving
from feed_twin.analysis.placed import diagnose_program, place
from feed_twin.analysis.repetitions import split_repetitions
from feed_twin.analysis.synthetic import NC_CONFIG, PROGRAM, as_trace, generate, write_with_nc
from feed_twin.analysis.twin import ModelDoc, Twin, drive_from_run
from feed_twin.io.measured import MeasuredDataError, load_measured

ROOT = Path(__file__).resolve().parent.parent
HIDDEN = {"constant_force": {"f_0_N": -120.0}, "stiction": {"F_hold_N": 20.0}}
FORCE_CONSTANT_N_A = 35.15
TRACE_PERIOD_TICKS = 20  # 50 Hz out of the 1 kHz loop
EFFORT_LATE_TICKS = 4  # the effort stamped 4 ms after the position
SETTLE_S = 0.065  # [s] the NC's wait after each exact stop (a Sinumerik 840D's, per block)
# the machine's NC: the program's NC configuration with the wait the user does not know of
MACHINE_NC = NC_CONFIG.replace(
    "  twin_axis: X\n", f"  twin_axis: X\n  exact_stop_settle_s: {SETTLE_S}\n"
)
MAP = """\
time: {{column: t_ms, unit: ms}}
position_sensor: motor_encoder
trace_filter: mean
signals:
  pos_meas_m: {{column: x_act_mm, unit: mm}}
  force_cmd_N: {{column: i_mot_A, unit: A, gain: {gain}}}
plausibility: {{travel_m: 1.0, max_speed_m_s: 0.5}}
"""


def once() -> str:
    """The program as the user has it: one run, every block an exact stop (G61), no waits."""
    return PROGRAM.replace("G64", "G61")


def program() -> str:
    """What the machine ran: the program three times, with rests between the runs."""
    lines = once().splitlines()
    moves = [ln for ln in lines[2:] if ln and ln != "M30"]
    return "\n".join(lines[:2] + moves + ["G4 P0.3"] + moves + ["G4 P0.5"] + moves + ["M30", ""])


def write_record(folder: Path, nominal: ModelDoc) -> Path:
    fine = generate(nominal, HIDDEN, program=program(), nc_config=MACHINE_NC)
    force = fine["u_drive_V"] * nominal.reference_gain
    late = np.concatenate((np.full(EFFORT_LATE_TICKS, force[0]), force[:-EFFORT_LATE_TICKS]))
    traced = as_trace(
        {"time_ms": fine["time_ms"], "x_act_mm": fine["x_act_mm"], "force_N": late},
        TRACE_PERIOD_TICKS,
    )
    columns = {
        "t_ms": traced["time_ms"],
        "x_act_mm": traced["x_act_mm"],
        "i_mot_A": -traced["force_N"] / FORCE_CONSTANT_N_A,  # counted against the motion
    }
    names = list(columns)
    table = np.column_stack([columns[k] for k in names])
    path = folder / "machine.csv"
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    return path


def hand_fit_rms(run, nominal: ModelDoc, start: int = 0) -> float:
    """RMS [N] of the effort left by a least-squares fit of the same effects by hand, on the
    samples from `start` on."""
    twin = Twin.compile(nominal)
    e0 = twin.simulate(drive_from_run(run), twin.nominal[None, :]).effort
    assert e0 is not None, "the record's map names an effort channel: the twin simulates it"
    e0 = e0[0]
    m = motion_from_position(
        run.t_s, run["pos_meas_m"], effort_sim=e0, lead_m=None, pole_pairs=None, travel_m=0.1
    )
    at_rest = 1.0 - moving(m)
    columns = [
        np.ones_like(e0),  # the weight
        np.tanh(m.v_m_s / m.speed_eps),  # sliding friction
        last_direction(m) * at_rest,  # the force held at rest
        np.gradient(e0, run.t_s),  # the channel delay
    ]
    Z = np.column_stack(columns)[start:]
    r = (run["force_cmd_N"] - e0)[start:]
    coef, *_ = np.linalg.lstsq(Z, r, rcond=None)
    return float(np.sqrt(np.mean((r - Z @ coef) ** 2)))


def main() -> None:
    nominal = ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        csv = write_record(folder, nominal)
        as_recorded = folder / "as_recorded.yaml"
        as_recorded.write_text(MAP.format(gain=FORCE_CONSTANT_N_A))
        declared = folder / "declared.yaml"
        declared.write_text(MAP.format(gain=-FORCE_CONSTANT_N_A))
        gcode = folder / "part.mpf"
        gcode.write_text(once())
        # the nominal model with the NC the program is planned on (not the machine's: its
        # waits are what the placement finds)
        planned = write_with_nc(nominal, folder / "nominal_nc.yaml")
        # the repetitions cut on the measured motion, the program placed on each (the CLI's
        # diagnose --repetitions --program: analysis.placed)
        clock = time.perf_counter()
        cut = split_repetitions(load_measured(csv, declared))
        runs = place(cut[:2], gcode, planned)
        placing_s = time.perf_counter() - clock
        assert runs[0] is not None
        # the same run and placed command, the current as recorded
        recorded = split_repetitions(load_measured(csv, as_recorded))[0]["force_cmd_N"]
        raw = runs[0].with_signals(force_cmd_N=recorded)
        twin = Twin.compile(nominal)
        try:
            check_effort_sign(raw, twin.simulate(drive_from_run(raw), twin.nominal[None, :]))
            sign_message = None
        except MeasuredDataError as exc:
            sign_message = str(exc).split(": ", 1)[1]
        clock = time.perf_counter()
        d, _, _, runs = diagnose_program(cut[:2], gcode, planned)
        diagnose_s = time.perf_counter() - clock
    assert runs[0] is not None
    hand = hand_fit_rms(runs[0], nominal)
    # the samples that are evidence (Twin.first_evidence: the first average the window before
    # the twin's start and its settling from a start read off averaged samples)
    start = twin.first_evidence(drive_from_run(runs[0]))
    trace = d.after_trace
    assert trace.effort_meas is not None and trace.effort_sim is not None
    assert d.after.effort_rms is not None, "the record has an effort: its residual has an RMS"
    assert d.validation is not None, "diagnose_program validates on the second repetition"
    after_evidence = float(np.sqrt(np.mean((trace.effort_meas - trace.effort_sim)[start:] ** 2)))
    hand_evidence = hand_fit_rms(runs[0], nominal, start)
    result = {
        "samples": int(sum(len(r.t_s) for r in cut)),
        "repetitions": len(cut),
        "reversed_sign_said": sign_message,
        "effects": {e.name: e.parameters for e in d.effects},
        "effort_rms_before_N": d.before.effort_rms,
        "effort_rms_after_N": d.after.effort_rms,
        "effort_rms_hand_fit_N": hand,
        "after_over_hand": d.after.effort_rms / hand,
        "evidence_from_sample": start,
        "effort_rms_after_on_evidence_N": after_evidence,
        "effort_rms_hand_fit_on_evidence_N": hand_evidence,
        "validation_effort_rel_err_pct": d.validation["after"]["effort_rel_err_pct"],
        "program_note": runs[0].warnings[-1],
        "placing_s": placing_s,
        "diagnose_s": diagnose_s,
        # the twin on the placed program against the machine: 28-38 ms behind on a real record
        "twin_behind_machine_ms": -1e3 * d.alignment.time_shift_s,
        "timings_s": d.timings_s,
        "notes": list(d.notes),
    }
    print(f"reversed sign: {sign_message}")
    print(f"{len(cut)} repetitions; named {list(result['effects'])}")
    print(
        f"effort RMS: nominal {d.before.effort_rms:.3f} N, workflow {d.after.effort_rms:.3f} N, "
        f"least squares by hand {hand:.3f} N"
    )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
