"""The discrepancy workflow on records without a command: the G-code program placed on them.

Placing (analysis.program) refines the program's time shifts and the record's position zero
against a twin's response to the command. The first placement can only use the nominal twin,
whose response lacks the very effects the workflow is about to find: a missing force lags or
holds the measured axis, and that moves the placed command. On a 1 kHz record with 15 N of
Coulomb friction hidden the command came out 30 us late (tests/test_analysis_repetitions.py);
on a 50 Hz exact-stop trace of a vertical axis held at rest by friction the zero came out 92 um
off (benchmarks/real_machine_record.py). So when the first pass names effects, the program is
placed again against the fitted model's response and the workflow runs once more from the
nominal model; that second diagnosis is the result.

That response leaves out the command delay the first pass fitted (analysis.command_delay_s;
the nominal model's own stays): for a command placed from a program, the placement's time shift
and a command delay are one timing, and the first pass's delay is the first placement's error
(fitted as -25 us on that record). Kept in the response, it put the second placement 26.7 us
late again, so the second pass named the same delay and, beside it, a friction of the wrong law
for the rest of the nominal twin's lag (a viscous friction of 193 N s/m, later a Stribeck term
in the Coulomb friction's place); without it the command lands 1.7 us from the record's own and the
Coulomb friction is named alone (15.00 N).

The timings cover every pass: each placement and each diagnosis, and `total_s` all of them (the
second diagnosis alone took 92 of 172 s on a real record).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.effects import Motion
from feed_twin.analysis.model_doc import COMMAND_DELAY_SLOT
from feed_twin.analysis.passes import PassListener, ignore
from feed_twin.analysis.program import command_from_program, nc_of_model
from feed_twin.analysis.report import Diagnosis
from feed_twin.analysis.rounds import Progress, noop
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import MeasuredRun


def place(
    runs: Sequence[MeasuredRun | None],
    program: str | Path,
    nominal: ModelDoc,
    response: ModelDoc | None = None,
) -> list[MeasuredRun | None]:
    """Each run (None stays None) with `program` planned on the nominal model's NC and placed
    against the response of `response` (default: the nominal model), with the nominal model's
    command delay in place of the one `response` fitted (module docstring: the placement is
    the command's timing)."""
    nc = nc_of_model(nominal.data, nominal.source)
    twin = nominal
    if response is not None:
        twin = response.set(COMMAND_DELAY_SLOT, nominal.get(COMMAND_DELAY_SLOT))
    return [
        None
        if r is None
        else command_from_program(r, program, nc=nc, nc_source=nominal.source, model=twin)
        for r in runs
    ]


def diagnose_program(
    runs: Sequence[MeasuredRun | None],
    program: str | Path,
    nominal: ModelDoc,
    *,
    progress: Progress = noop,
    passes: PassListener = ignore,
    model_path: str = "model.yaml",
    placed: list[MeasuredRun | None] | None = None,
    placing_s: float = 0.0,
) -> tuple[Diagnosis, ModelDoc, Motion, list[MeasuredRun | None]]:
    """Diagnose `runs[0]` (validated on `runs[1]` when there is one) with `program` placed on
    each run (module docstring); also returns the runs as placed for the result. `placed`: the
    runs as `place(runs, program, nominal)` gave them, if the caller has placed them already
    (to report a program that does not fit the record before anything is written), and the
    seconds that took (`placing_s`, counted in the timings' total). `passes` hears each pass of
    each diagnosis (analysis.passes): the second, on the program placed again, starts over."""
    clock = time.perf_counter() - placing_s
    timings = {"placing_s": placing_s}
    if placed is None:
        placed = place(runs, program, nominal)
        timings["placing_s"] = time.perf_counter() - clock
    diagnosis, doc, motion = _diagnose_placed(runs, placed, nominal, progress, passes, model_path)
    if not diagnosis.effects:
        return _timed(diagnosis, timings, {}, clock), doc, motion, placed
    first = {f"first_pass_{k}": v for k, v in diagnosis.timings_s.items()}
    found = ", ".join(e.name for e in diagnosis.effects)
    progress(f"placing the program again against the response of the model with {found}")
    again_at = time.perf_counter()
    placed = place(runs, program, nominal, doc)
    timings["placing_again_s"] = time.perf_counter() - again_at
    diagnosis, doc, motion = _diagnose_placed(runs, placed, nominal, progress, passes, model_path)
    again = f"the program was placed again against the response of the model with {found}"
    diagnosis = dataclasses.replace(diagnosis, notes=(again, *diagnosis.notes))
    return _timed(diagnosis, timings, first, clock), doc, motion, placed


def _timed(
    diagnosis: Diagnosis, placing: dict[str, float], first: dict[str, float], clock: float
) -> Diagnosis:
    """The diagnosis with the timings of every pass: the placements, the first diagnosis
    (`first_pass_...`), the last one's own, and `total_s` over all of them from `clock`."""
    last = {k: v for k, v in diagnosis.timings_s.items() if k != "total_s"}
    if first:
        last = {f"second_pass_{k}": v for k, v in last.items()}
        last["second_pass_total_s"] = diagnosis.timings_s.get("total_s", 0.0)
    timings = placing | first | last | {"total_s": time.perf_counter() - clock}
    return dataclasses.replace(diagnosis, timings_s=timings)


def _diagnose_placed(
    runs: Sequence[MeasuredRun | None],
    placed: list[MeasuredRun | None],
    nominal: ModelDoc,
    progress: Progress,
    passes: PassListener,
    model_path: str,
) -> tuple[Diagnosis, ModelDoc, Motion]:
    first, validate = placed[0], placed[1] if len(placed) > 1 else None
    assert first is not None and runs[0] is not None
    for note in first.warnings[len(runs[0].warnings) :]:
        progress(f"warning: {note}")  # where the program was placed
    return diagnose(
        first, nominal, validate=validate, progress=progress, passes=passes, model_path=model_path
    )
