"""The progress bar of long jobs (feed_twin.io.progress): on a terminal it shows the step, the
percent, the simulated time and the ETA; under --json or into a pipe it shows nothing."""

from __future__ import annotations

import io
import os
import pty
import re
import subprocess
import sys
from pathlib import Path

import pytest

from feed_twin.io.progress import Progress, wanted

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"


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
    controller, terminal = pty.openpty()
    env = {**os.environ, "COLUMNS": "160"}
    proc = subprocess.Popen(argv, stdout=terminal, stderr=terminal, env=env, cwd=ROOT)
    os.close(terminal)
    shown = _read_all(controller)
    os.close(controller)
    return proc.wait(timeout=120), shown


@pytest.mark.slow
def test_a_run_on_a_terminal_shows_progress_and_under_json_does_not(tmp_path):
    code, shown = _run_on_a_terminal(tmp_path, "--name", "a")
    assert code == 0, shown
    assert "compiling every axis's kernels" in shown or "simulating: " in shown, shown
    assert re.search(r"\d+%\|", shown) and "s simulated [" in shown, shown
    code, shown = _run_on_a_terminal(tmp_path, "--name", "b", "--json")
    assert code == 0, shown
    assert "s simulated [" not in shown and "%|" not in shown, shown
