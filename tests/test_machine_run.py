"""`feed-twin run PROGRAM --config MACHINE.yaml`: the machine twin in-process, its bag (read back
by an independent reader), dashboard, summary and --json line, and its one-line refusals."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from feed_twin.cli import main as cli_main
from feed_twin.io.bag import BagError, BagReader
from feed_twin.io.dashboard import rerun_binary
from feed_twin.machine.config import load_machine_config, load_run_config
from feed_twin.machine.simulate import simulate_machine
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.program import simulate_program

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
AXIS = ROOT / "config" / "axis_default.yaml"
PROGRAM = "G90 G54 G17\nG1 B0\nG1 X10 Y5 Z-5 F3000\nG2 X20 Y5 I5 J0 B15\nG0 X0 Y0 Z0\nM2\n"


def run(tmp_path: Path, capsys, *extra: str, program: str = PROGRAM, config: Path = MACHINE):
    path = tmp_path / "part.ngc"
    path.write_text(program)
    argv = ["run", str(path), "--config", str(config), "--out", str(tmp_path), "--name", "m"]
    code = cli_main([*argv, "--json", "--settle", "0.05", "--in-process", *extra])
    out, err = capsys.readouterr()
    return code, json.loads(out.strip().splitlines()[-1]), err


def test_machine_run_records_every_axis_and_the_contour_error(tmp_path, capsys):
    code, record, _ = run(tmp_path, capsys)
    assert code == 0, record
    assert record["axes"] == ["x", "y", "z"]
    expected = simulate_machine(load_machine_config(MACHINE), tmp_path / "part.ngc", settle_s=0.05)
    assert record["contour_error_max_m"] == pytest.approx(expected.summary()["contour_error_max_m"])
    assert set(record["following_error_max_m"]) == {"x", "y", "z"}
    # an independent reader (mcap_ros2) gives back what the run computed
    reader = BagReader(record["bag"])
    contour = reader.columns("/cnc/contour_error", ["data"])
    assert np.allclose(contour["data"], expected.contour.normal_m, rtol=0, atol=1e-15)
    assert np.allclose(contour["log_time_s"], expected.t_s, atol=1e-9)
    state = reader.columns("/cnc/z/state", ["table_position", "following_error", "i_q"])
    assert np.allclose(state["table_position"], expected.actual[:, 2], atol=1e-15)
    # at the start Z holds its weight minus the counterbalance, 0.405 A (test_machine_config),
    # within the current sensor's noise (0.02 A) and its control ripple
    assert state["i_q"][0] == pytest.approx(0.405, abs=0.06)
    b = reader.columns("/cnc/b/command", ["position"])["position"]
    assert b[-1] == pytest.approx(np.radians(15.0))
    subprocess.run([str(rerun_binary()), "rrd", "verify", record["rrd"]], check=True, timeout=60)


def test_an_axis_file_runs_in_process_as_a_one_axis_machine(tmp_path, capsys):
    program = "G90 G54\nG1 X5 F3000\nG0 X0\nM2\n"
    code, record, _ = run(tmp_path, capsys, program=program, config=AXIS)
    assert code == 0, record
    assert record["axes"] == ["x"] and record["mode"] == "axis in-process"
    machine = load_run_config(AXIS)
    assert (machine.name, machine.simulated, machine.axis_file) == ("cnc", ("X",), True)
    expected = simulate_program(load_axis_config(AXIS), tmp_path / "part.ngc", settle_s=0.05)
    state = BagReader(record["bag"]).columns("/cnc/x/state", ["table_position"])
    assert np.array_equal(state["table_position"], expected.actual[:, 0])


def test_axes_on_an_axis_file_need_in_process(tmp_path, capsys):
    path = tmp_path / "part.ngc"
    path.write_text("G1 X5 F3000\n")
    argv = ["run", str(path), "--config", str(AXIS), "--out", str(tmp_path), "--axes", "X"]
    assert cli_main([*argv, "--json"]) == 1
    reason = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["reason"]
    assert re.fullmatch(r"--axes needs a machine config or --in-process; .*axis_default.yaml is "
                        r"one axis", reason)  # fmt: skip


def test_axes_subset_simulates_only_those(tmp_path, capsys):
    code, record, _ = run(tmp_path, capsys, "--axes", "X,z")
    assert code == 0, record
    assert record["axes"] == ["x", "z"]
    reader = BagReader(record["bag"])
    assert len(reader.columns("/cnc/y/command", ["position"])["position"]) > 0
    with pytest.raises(BagError, match="no topic ./cnc/y/state. in the bag"):
        reader.columns("/cnc/y/state", ["table_position"])


@pytest.mark.parametrize(
    ("extra", "program", "config", "message"),
    [
        ((), "G1 X1 A5 F100\n", MACHINE,
         r"G-code error, nothing was started: .*part.ngc:1:7: word 'A5': unknown word \(axis A"),
        (("--axes", "X,B"), PROGRAM, MACHINE, r"--axes X,B: axis B has no plant"),
        (("--realtime",), PROGRAM, MACHINE, r"--realtime: not available .* run in-process"),
        (("--axes", "Y"), "G1 X5 F3000\n", AXIS,
         r"--axes Y: axis Y has no plant \(simulated axes: X\)"),
    ],
)  # fmt: skip
def test_refusals_are_one_line_before_anything_runs(
    tmp_path, capsys, extra, program, config, message
):
    code, record, err = run(tmp_path, capsys, *extra, program=program, config=config)
    assert code == 1
    assert record["exit_code"] == 1
    assert len(err.strip().splitlines()) == 1
    assert re.search(message, record["reason"]), record["reason"]
    assert not (tmp_path / "m").exists()
