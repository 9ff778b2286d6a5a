"""`feed-twin diagnose` and `feed-twin simulate`: the discrepancy workflow from the shell.

    feed-twin diagnose MEASURED --config NOMINAL [--map MAP] [--program PROGRAM]
                       [--validate OTHER[:T0:T1] | --repetitions] [--segment T0:T1]
                       [--rate HZ] --out DIR

With --repetitions, --program names one run of the program: it is placed on each repetition.
    feed-twin simulate --config MODEL --measured MEASURED [--map MAP] [--program PROGRAM]
                       [--segment T0:T1] --out traces.csv

Without --map, a file `<MEASURED stem>_map.yaml` next to the data is used if it exists.
--rate HZ: the rows were written at HZ and the time is their index (a monitoring log without
a time column; the same as `time: {index: true, rate_hz: HZ}` in the map). --segment and the
`:T0:T1` of --validate cut a record before its plausibility checks, which see only that part.
`diagnose` writes DIR/report.md, DIR/report.json, DIR/model.yaml, PNG plots and DIR/diagnose.rrd
and prints its progress. `simulate` writes t_s and, for every canonical signal the map provides,
the measured `<name>` and the simulated `sim_<name>` (plus `sim_` columns of the signals the
twin produces but the record lacks).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

# One BLAS thread, set before numpy loads OpenBLAS (feed_twin.cli imports this module first):
# the workflow's linear algebra is tall and thin (20001 x a few), which a second thread does
# not speed up, while OpenBLAS's threads spin for the core the engine's batch threads and the
# machine's other work need. On 2 shared cores at load 6 the same diagnose of a 20 s, 1 kHz
# record took 0.9 to 10.5 s (CPU 1.6 to 7.0 s) with them, 0.8 to 1.4 s with one
# (benchmarks/diagnose_record_speed.py). A value the user set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from feed_twin.core.config import ConfigError  # noqa: E402
from feed_twin.io.measured import (  # noqa: E402
    MeasuredDataError,
    MeasuredRun,
    load_measured,
    parse_segment,
)

# The files whose presence marks a directory as an earlier diagnosis's (analysis/report.py).
REPORT_FILES = ("report.md", "report.json", "model.yaml", "diagnose.rrd")


def _check_out(out: Path, *, directory: bool) -> None:
    """An --out that names the wrong kind of thing is refused before any work is done."""
    if directory and out.exists() and not out.is_dir():
        raise MeasuredDataError(f"--out {out}: is an existing file; name a directory")
    written = [name for name in REPORT_FILES if directory and (out / name).exists()]
    if written:
        raise MeasuredDataError(
            f"--out {out}: holds a report already ({', '.join(written)}); choose another "
            "directory, nothing was written"
        )
    if not directory and out.is_dir():
        raise MeasuredDataError(f"--out {out}: is a directory; name the CSV file to write")


def _map_for(measured: Path, given: str | None) -> Path:
    if given is not None:
        return Path(given)
    candidate = measured.with_name(f"{measured.stem}_map.yaml")
    if candidate.exists():
        return candidate
    raise MeasuredDataError(
        f"{measured}: no column map given (--map) and no {candidate.name} next to the data"
    )


def split_validate(text: str) -> tuple[str, str | None]:
    """`FILE[:T0:T1]` -> (FILE, 'T0:T1' or None): the part of a validation record to use."""
    head, sep, t1 = text.rpartition(":")
    path, sep0, t0 = head.rpartition(":")
    if sep and sep0 and path:
        try:
            _ = (float(t0), float(t1))
        except ValueError:
            return text, None
        return path, f"{t0}:{t1}"
    return text, None


def _load(
    measured: str,
    map_path: str | None,
    program: str | None = None,
    model=None,
    window: str | None = None,
    *,
    command: bool = True,
    rate_hz: float | None = None,
) -> MeasuredRun:
    """The record, cut to `window` (before its plausibility checks), with the program placed
    on it; `command=False`: the command may still be missing (a program placed later, on each
    repetition)."""
    path = Path(measured)
    cut = None if window is None else parse_segment(window)
    run = load_measured(path, _map_for(path, map_path), rate_hz=rate_hz, window=cut)
    if program is not None:
        run = _placed(run, program, model)
    if command and "pos_cmd_m" not in run and "vel_cmd_m_s" not in run:
        raise MeasuredDataError(
            f"{measured}: the record has no command (pos_cmd_m or vel_cmd_m_s); give the G-code "
            "that ran with --program"
        )
    if "pos_meas_m" not in run:
        raise MeasuredDataError(f"{measured}: the map provides no measured position pos_meas_m")
    return run


def _placed(run: MeasuredRun, program: str, model) -> MeasuredRun:
    from feed_twin.analysis.placed import place

    placed = place([run], program, model)[0]
    assert placed is not None
    return placed


def configure_diagnose(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("measured", help="measured run: CSV file or rosbag2 directory")
    parser.add_argument("--config", required=True, help="nominal model YAML")
    parser.add_argument("--map", help="column map YAML (default: <measured stem>_map.yaml)")
    parser.add_argument("--program", help="G-code that ran, when the record has no command")
    parser.add_argument(
        "--validate",
        help="a second measured run to validate the result on, FILE or FILE:t0:t1 (a part of "
        "it; the same file as the record validates on another part of it)",
    )
    parser.add_argument(
        "--segment", help="identify on the part t0:t1 [s] of the record only (e.g. 2.5:14)"
    )
    _rate_argument(parser)
    parser.add_argument(
        "--repetitions",
        action="store_true",
        help="the record holds the program several times: identify on the first, validate on "
        "the others",
    )
    parser.add_argument("--out", required=True, help="output directory")


def main_diagnose(args: argparse.Namespace) -> int:
    from feed_twin.analysis import wording
    from feed_twin.analysis.diagnose import diagnose, write_model
    from feed_twin.analysis.passes import Pass
    from feed_twin.analysis.placed import diagnose_program, place
    from feed_twin.analysis.report_files import write_report
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.io.progress import PassBar, wanted

    # a person at a terminal sees each pass, its percent and ETA on a bar below the lines
    bar = PassBar(enabled=wanted(json_out=False))
    last: list[Pass] = []

    def progress(text: str) -> None:
        bar.say(f"[diagnose] {text}")

    def passes(step: Pass) -> None:
        last[:] = [step]
        bar.begin(step.name, done=step.done, planned=step.planned, simulated_s=step.simulated_s)

    from feed_twin.gcode.errors import GcodeError

    try:
        _check_out(Path(args.out), directory=True)
        doc = ModelDoc.load(args.config)
        program: str | None = args.program
        # with --program the runs are placed here and, once more, by diagnose_program
        # (analysis/placed.py): a program that does not fit is said before anything is written
        unplaced = program is None
        rate = args.rate
        run = _load(
            args.measured, args.map, None, doc, args.segment, command=unplaced, rate_hz=rate
        )
        other = None
        if args.validate:
            path, part = split_validate(args.validate)
            other = _load(path, args.map, None, doc, part, command=unplaced, rate_hz=rate)
        more: list[MeasuredRun] = []
        if args.repetitions:
            # the program file holds one run of what the record repeats: placed on each
            run, other, more = _repetitions(run, other, progress)
        measured = [run, other, *more]
        clock = time.perf_counter()
        placed = None if program is None else place(measured, program, doc)
        placing_s = time.perf_counter() - clock
        for w in run.warnings:  # the loader's; diagnose_program says where it placed the program
            progress(f"warning: {w}")
    except (MeasuredDataError, ConfigError, GcodeError) as exc:
        print(f"feed-twin diagnose: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model_path = out / "model.yaml"
    try:
        if program is None:
            diagnosis, final_doc, motion = diagnose(
                run, doc, validate=other, progress=progress, passes=passes,
                model_path=str(model_path),
            )  # fmt: skip
        else:
            diagnosis, final_doc, motion, placed = diagnose_program(
                measured, program, doc, progress=progress, passes=passes,
                model_path=str(model_path), placed=placed, placing_s=placing_s,
            )  # fmt: skip
            more = [r for r in placed[2:] if r is not None]
    except (MeasuredDataError, ConfigError, GcodeError) as exc:
        bar.close()
        print(f"feed-twin diagnose: {exc}", file=sys.stderr)
        return 2
    except BaseException:
        bar.close()  # a traceback is not written over a bar
        raise
    if more:
        diagnosis = _validate_more(diagnosis, final_doc, more, progress)
    if last:  # the plots and the recording take seconds too
        bar.begin("writing the report", done=last[0].planned, planned=last[0].planned,
                  simulated_s=last[0].simulated_s)  # fmt: skip
    write_model(final_doc, model_path, diagnosis.effects)
    written = write_report(diagnosis, out, v_m_s=motion.v_m_s)
    bar.close()
    from feed_twin.plant.slot_specs import with_unit

    progress(diagnosis.verdict)
    for e in diagnosis.effects:
        values = ", ".join(with_unit(k, v) for k, v in e.parameters.items())
        progress(f"  {e.name}: {values} ({100 * e.explained_fraction:.3g} % of the cost)")
    b, a = diagnosis.before, diagnosis.after
    progress(
        f"FE deviation RMS {b.fe_dev_rms_m * 1e6:.3g} -> {a.fe_dev_rms_m * 1e6:.3g} um, "
        f"effort rel. error {wording.percent(b.effort_rel_err_pct)} -> "
        f"{wording.percent(a.effort_rel_err_pct)}"
    )
    if diagnosis.validation is not None:
        v = diagnosis.validation["after"]
        progress(
            f"validation: position {wording.percent(v['pos_rel_err_pct'])}, effort "
            f"{wording.percent(v['effort_rel_err_pct'])}"
        )
    progress("wrote " + ", ".join(str(p) for p in written + [model_path]))
    return 0


def _repetitions(run: MeasuredRun, other: MeasuredRun | None, progress):
    """(identification run, validation run, further runs) of a record with repetitions."""
    from feed_twin.analysis.repetitions import find_period, split_repetitions

    if other is not None:
        raise MeasuredDataError(
            "--repetitions validates on the record's own repetitions; leave out --validate"
        )
    found = find_period(run)
    parts = split_repetitions(run)
    if found is None or len(parts) < 2:
        raise MeasuredDataError(
            f"{run.source}: --repetitions: no repetition of the program found (no later part of "
            "the record matches the first run's motion with a correlation >= 0.8)"
        )
    period, r = found
    progress(
        f"found {len(parts)} repetitions, {period:.3f} s apart on average (least match {r:.3f}); "
        f"identifying on the first ({parts[0].t_s[0]:.3f} to {parts[0].t_s[-1]:.3f} s), "
        "validating on the others"
    )
    return parts[0], parts[1], parts[2:]


def _validate_more(diagnosis, doc, runs: list[MeasuredRun], progress):
    """The validation metrics of the fitted model on further runs, as notes of the report."""
    import dataclasses

    from feed_twin.analysis.diagnose import run_metrics
    from feed_twin.analysis.twin import Twin, drive_from_run

    twin = Twin.compile(doc)
    notes = []
    for run in runs:
        out = twin.simulate(drive_from_run(run), twin.nominal[None, :])
        m = run_metrics(run, out)
        effort = "n/a" if m.effort_rel_err_pct is None else f"{m.effort_rel_err_pct:.3f}"
        note = (
            f"validation on {run.source}: position {m.pos_rel_err_pct:.4g} %, effort "
            f"{effort} %, FE deviation RMS {m.fe_dev_rms_m * 1e6:.3f} um"
        )
        progress(note)
        notes.append(note)
    return dataclasses.replace(diagnosis, notes=diagnosis.notes + tuple(notes))


def configure_simulate(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="model YAML")
    parser.add_argument("--measured", required=True, help="measured run: CSV or rosbag2 dir")
    parser.add_argument("--map", help="column map YAML (default: <measured stem>_map.yaml)")
    parser.add_argument("--program", help="G-code that ran, when the record has no command")
    parser.add_argument("--segment", help="simulate the part t0:t1 [s] of the record only")
    _rate_argument(parser)
    parser.add_argument("--out", required=True, help="CSV file to write")


def _rate_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="the record has no time column: its rows were written at HZ (time = row / HZ)",
    )


def simulate_traces(
    run: MeasuredRun, doc, step: Callable[[str, int], None] | None = None
) -> dict[str, np.ndarray]:
    """t_s, every measured canonical signal and its simulated `sim_` twin; `step(name, done)`
    hears each of its two steps begin (the compilation, the simulation)."""
    from feed_twin.analysis.twin import Twin, drive_from_run

    if step is not None:
        step("compiling the model", 0)
    twin = Twin.compile(doc)
    drive = drive_from_run(run)
    if step is not None:
        step("simulating the record", 1)
    out = twin.simulate(drive, twin.nominal[None, :])
    if not out.ok[0]:
        raise RuntimeError(f"{doc.source} diverged on {run.source}")
    simulated = {"pos_meas_m": out.x_m[0], "pos_cmd_m": drive.pos_ref_m}
    if out.effort is not None:
        simulated[twin.effort_name] = out.effort[0]
    if out.voltage_q is not None:
        simulated["voltage_q_V"] = out.voltage_q[0]
    for name in run:
        if name.startswith("disturbance_"):
            simulated[name] = run[name]  # known inputs: the twin gets exactly these
    columns: dict[str, np.ndarray] = {"t_s": run.t_s}
    for name in run:
        columns[name] = run[name]
        if name in simulated:
            columns[f"sim_{name}"] = simulated[name]
    for name, values in simulated.items():
        columns.setdefault(f"sim_{name}", values)
    return columns


def main_simulate(args: argparse.Namespace) -> int:
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.gcode.errors import GcodeError

    try:
        _check_out(Path(args.out), directory=False)
        doc = ModelDoc.load(args.config)
        run = _load(args.measured, args.map, args.program, doc, args.segment, rate_hz=args.rate)
    except (MeasuredDataError, ConfigError, GcodeError) as exc:
        print(f"feed-twin simulate: {exc}", file=sys.stderr)
        return 2
    from feed_twin.io.progress import PassBar, wanted

    # compiling a model and simulating a long record take seconds: said on a terminal
    bar = PassBar(enabled=wanted(json_out=False))

    def step(name: str, done: int) -> None:
        bar.begin(name, done=done, planned=2)

    try:
        columns = simulate_traces(run, doc, step)
    except (MeasuredDataError, ConfigError) as exc:
        print(f"feed-twin simulate: {exc}", file=sys.stderr)
        return 2
    finally:
        bar.close()
    names = list(columns)
    table = np.column_stack([columns[n] for n in names])
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(out, table, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    print(f"[simulate] wrote {len(names)} columns x {len(table)} samples to {out}")
    return 0


# The registry in feed_twin/cli.py wants configure/main per module: this module is `diagnose`,
# feed_twin.analysis.simulate_cli re-exports the `simulate` pair.
configure = configure_diagnose
main = main_diagnose
