"""The progress bar of long jobs (feed_twin.io.progress): on a terminal it shows the step, the
percent, the simulated time and the ETA; under --json or into a pipe it shows nothing. A
diagnosis shows its passes (feed_twin.analysis.passes) the same way."""

from __future__ import annotations

import io
import os
import pty
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feed_twin.analysis.cli import simulate_traces
from feed_twin.analysis.diagnose import Options, diagnose
from feed_twin.analysis.passes import Pass
from feed_twin.analysis.synthetic import generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured
from feed_twin.io.progress import PassBar, Progress, wanted

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
EMPS_NOMINAL = ROOT / "config" / "emps_nominal.yaml"


def _read_all(fd: int) -> str:
    chunks = []
    while True:
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # the terminal's other end closed
            break
        if not chunk:
            break
        chunks.append(chunk)
    return b"".join(chunks).decode(errors="replace")


def test_a_terminal_sees_the_step_percent_simulated_time_and_eta():
    controller, terminal = pty.openpty()
    with os.fdopen(terminal, "w", closefd=True) as stream:
        assert wanted(json_out=False, stream=stream)
        assert not wanted(json_out=True, stream=stream)
        bar = Progress(total_s=4.0, enabled=True, stream=stream, min_interval_s=0.0)
        bar.stage("compiling")
        bar.update(1.0)
        bar.update(9.0)  # past the planned end: held at 100 %
        bar.close()
    shown = _read_all(controller)
    os.close(controller)
    assert "compiling: " in shown
    assert re.search(r"25%\|.*\| 1\.00/4\.00 s simulated \[", shown), shown
    assert "100%" in shown and "4.00/4.00 s simulated" in shown


def test_a_pipe_or_a_file_sees_nothing():
    stream = io.StringIO()
    assert not wanted(json_out=False, stream=stream)
    bar = Progress(total_s=4.0, enabled=wanted(json_out=False, stream=stream), stream=stream)
    bar.stage("compiling")
    bar.update(1.0)
    bar.close()
    assert stream.getvalue() == ""


def _run_on_a_terminal(tmp_path: Path, *extra: str) -> tuple[int, str]:
    """`feed-twin run` of a machine in-process with stderr (and stdout) on a terminal."""
    program = tmp_path / "p.ngc"
    program.write_text("G90 G54 G17\nG1 X20 Y10 F3000\nG0 X0 Y0\nM2\n")
    argv = [sys.executable, "-m", "feed_twin.cli", "run", str(program), "--config", str(MACHINE),
            "--in-process", "--settle", "0.05", "--out", str(tmp_path), *extra]  # fmt: skip
    return on_a_terminal(argv)


def on_a_terminal(argv: list[str]) -> tuple[int, str]:
    """Exit code and everything `argv` wrote, its stdout and stderr on one terminal."""
    controller, terminal = pty.openpty()
    env = {**os.environ, "COLUMNS": "160"}
    proc = subprocess.Popen(argv, stdout=terminal, stderr=terminal, env=env, cwd=ROOT)
    os.close(terminal)
    shown = _read_all(controller)
    os.close(controller)
    return proc.wait(timeout=300), shown


@pytest.mark.slow
def test_a_run_on_a_terminal_shows_progress_and_under_json_does_not(tmp_path):
    code, shown = _run_on_a_terminal(tmp_path, "--name", "a")
    assert code == 0, shown
    assert "compiling every axis's kernels" in shown or "simulating: " in shown, shown
    assert re.search(r"\d+%\|", shown) and "s simulated [" in shown, shown
    code, shown = _run_on_a_terminal(tmp_path, "--name", "b", "--json")
    assert code == 0, shown
    assert "s simulated [" not in shown and "%|" not in shown, shown


def test_a_job_of_passes_shows_each_pass_its_percent_and_the_record_simulated():
    controller, terminal = pty.openpty()
    with os.fdopen(terminal, "w", closefd=True) as stream:
        bar = PassBar(enabled=True, stream=stream, min_interval_s=0.0, tick_s=0.02)
        bar.begin("compiling the nominal model", done=0, planned=8, simulated_s=0.0)
        bar.begin("round 1 of at most 5", done=1, planned=8, simulated_s=24.8)
        time.sleep(0.5)  # a long pass: the bar is drawn again while it goes on
        bar.say("[diagnose] round 1: fitting coulomb_friction", stream)
        bar.begin("final joint re-fit", done=6, planned=8, simulated_s=1190.4)
        bar.close()
    shown = _read_all(controller)
    os.close(controller)
    assert "compiling the nominal model:   0%|" in shown, shown
    assert re.search(r"round 1 of at most 5:  12%\|.*\| pass 1/8, 25 s simulated \[", shown)
    assert re.search(r"final joint re-fit:  75%\|.*\| pass 6/8, 1190 s simulated \[", shown)
    assert shown.count("round 1 of at most 5: ") >= 5, shown
    # the job's own line is whole: the bar is cleared before it and drawn again below it
    assert "\n[diagnose] round 1: fitting coulomb_friction" in shown.replace("\r", "\n"), shown


def test_passes_into_a_pipe_show_only_the_jobs_lines():
    stream = io.StringIO()
    bar = PassBar(enabled=wanted(json_out=False, stream=stream), stream=stream)
    bar.begin("round 1 of at most 5", done=1, planned=8, simulated_s=24.8)
    bar.say("[diagnose] round 1: fitting coulomb_friction", stream)
    bar.close()
    assert stream.getvalue() == "[diagnose] round 1: fitting coulomb_friction\n"


def _synthetic_record(tmp_path: Path) -> tuple[ModelDoc, Path, Path]:
    """A synthetic 1 kHz record of the EMPS model with 15 N of Coulomb friction hidden."""
    nominal = ModelDoc.load(EMPS_NOMINAL)
    columns = generate(nominal, {"coulomb_friction": {"F_c_N": 15.0}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    return nominal, tmp_path / "run.csv", map_path


def test_a_diagnosis_announces_its_passes_with_the_record_time_simulated(tmp_path):
    nominal, csv, map_path = _synthetic_record(tmp_path)
    run = load_measured(csv, map_path)
    seen: list[Pass] = []
    d, _, _ = diagnose(run, nominal, options=Options(max_effects=1), passes=seen.append)
    assert [e.name for e in d.effects] == ["coulomb_friction"]
    names = [p.name for p in seen]
    # one round planned: the nominal, the round, the joint selection, the joint re-fit, the
    # appraisal
    assert names == [
        "compiling the nominal model",
        "simulating the nominal twin",
        "round 1 of at most 1",
        "joint selection",
        "final joint re-fit",
        "appraising the final model",
    ], names
    assert [p.done for p in seen] == [0, 0, 1, 2, 3, 4]
    assert {p.planned for p in seen} == {5}
    record_s = float(run.t_s[-1] - run.t_s[0])
    # the first round starts after the nominal simulation, one record long; the round's fits
    # simulate the record again for each parameter set
    assert seen[2].simulated_s == pytest.approx(record_s)
    assert seen[3].simulated_s > 10 * record_s
    assert seen[4].simulated_s >= seen[3].simulated_s
    counts = [p.simulated_s / record_s for p in seen]
    assert counts == sorted(counts) and all(c == pytest.approx(round(c)) for c in counts)


def _diagnose_on(tmp_path: Path, csv: Path, map_path: Path, out: str, *, terminal: bool):
    """`feed-twin diagnose` of the record, its stdout and stderr on a terminal or a pipe."""
    argv = [sys.executable, "-m", "feed_twin.cli", "diagnose", str(csv), "--config",
            str(EMPS_NOMINAL), "--map", str(map_path), "--out", str(tmp_path / out)]  # fmt: skip
    if terminal:
        return on_a_terminal(argv)
    done = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT)
    return done.returncode, done.stdout + done.stderr


@pytest.mark.slow
def test_a_diagnosis_on_a_terminal_shows_its_passes_and_into_a_pipe_does_not(tmp_path):
    _, csv, map_path = _synthetic_record(tmp_path)
    code, shown = _diagnose_on(tmp_path, csv, map_path, "a", terminal=True)
    assert code == 0, shown
    assert "compiling the nominal model: " in shown, shown
    # the nominal, 5 rounds at most, the joint selection, the joint re-fit, the appraisal
    assert re.search(r"round 1 of at most 5: +\d+%\|.*\| pass 1/9, \d+ s simulated \[", shown)
    assert "writing the report: 100%|" in shown, shown
    code, shown = _diagnose_on(tmp_path, csv, map_path, "b", terminal=False)
    assert code == 0, shown
    assert "[diagnose] round 1: fitting coulomb_friction" in shown, shown
    assert "%|" not in shown and "s simulated [" not in shown, shown


def test_a_job_of_steps_without_a_simulated_time_shows_none():
    controller, terminal = pty.openpty()
    with os.fdopen(terminal, "w", closefd=True) as stream:
        bar = PassBar(enabled=True, stream=stream, min_interval_s=0.0)
        bar.begin("compiling the model", done=0, planned=2)
        bar.begin("simulating the record", done=1, planned=2)
        bar.close()
    shown = _read_all(controller)
    os.close(controller)
    assert re.search(r"simulating the record:  50%\|.*\| pass 1/2 \[", shown), shown
    assert "simulated [" not in shown and not shown.lstrip().startswith("0%"), shown


def test_simulate_names_its_steps(tmp_path):
    nominal, csv, map_path = _synthetic_record(tmp_path)
    steps: list[tuple[str, int]] = []
    columns = simulate_traces(
        load_measured(csv, map_path), nominal, lambda name, done: steps.append((name, done))
    )
    assert steps == [("compiling the model", 0), ("simulating the record", 1)]
    assert "sim_pos_meas_m" in columns
