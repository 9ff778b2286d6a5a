"""Every mode of `feed-twin run` ends with the same report (tests/run_report_support.py): the
machine in-process run and its shadow here, a refusal before anything started in every mode;
the node-set modes check it on their own runs (run_report_support.MODES: the axis and the
machine config each in `run`, `run --shadow` and `run --nc linuxcnc --shadow`)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from run_report_support import MODES, assert_report

from feed_twin.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
AXIS = ROOT / "config" / "axis_default.yaml"
PROGRAM = "G90 G54 G17\nG1 X10 Y5 F3000\nG0 X0 Y0\nM2\n"


def _run(tmp_path: Path, capsys, config: Path, *extra: str, program: str = PROGRAM):
    path = tmp_path / "part.ngc"
    path.write_text(program)
    argv = ["run", str(path), "--config", str(config), "--out", str(tmp_path), "--name", "m"]
    code = cli_main([*argv, "--json", *extra])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("config", "extra", "mode", "message"),
    [
        (AXIS, (), "axis nodes", "G-code error, nothing was started"),
        (AXIS, ("--shadow", "--single-process"), "axis nodes, one process shadow",
         "cannot be combined with --single-process"),
        (AXIS, ("--nc", "linuxcnc"), "axis LinuxCNC shadow", "add --shadow"),
        (MACHINE, ("--in-process", "--axes", "X,B"), "machine in-process", "axis B has no plant"),
        (AXIS, ("--in-process", "--axes", "Y"), "axis in-process", "axis Y has no plant"),
        (MACHINE, ("--single-process",), "machine nodes, one process", "not available"),
        (MACHINE, ("--shadow", "--realtime"), "machine nodes shadow", "--realtime: not available"),
        (MACHINE, ("--nc", "linuxcnc"), "machine LinuxCNC shadow", "add --shadow"),
    ],
)  # fmt: skip
def test_a_refusal_in_every_mode_ends_with_the_same_report(
    tmp_path, capsys, config, extra, mode, message
):
    program = "G1 X1 Q5 F100\nM2\n" if not extra else PROGRAM
    code, out, err = _run(tmp_path, capsys, config, *extra, program=program)
    assert code == 1
    assert message in err and len(err.strip().splitlines()) == 1, err
    record = assert_report(out)
    assert record["mode"] == mode and message in record["reason"]
    assert record["bag"] is None and record["timing_sim_time_s"] is None
    assert f"run:                  {mode}, exit code 1\n" in out
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize(("mode", "test_file"), sorted(MODES.items()))
def test_every_mode_of_a_node_set_run_has_its_report_checked(mode, test_file):
    """Each of the six node-set modes (axis and machine config, each in `run`, `run --shadow`
    and `run --nc linuxcnc --shadow`) is named by a test that checks its finished run's report
    with run_report_support.assert_report(..., mode=...)."""
    text = (ROOT / "tests" / test_file).read_text()
    call = re.compile(rf'assert_report\([\w.]+, mode="{re.escape(mode)}"\)')
    assert call.search(text), f"{test_file} does not check the report of a {mode} run"


@pytest.mark.parametrize("shadow", [(), ("--shadow",)])
def test_the_machine_in_process_ends_with_the_report_of_every_mode(tmp_path, capsys, shadow):
    code, out, err = _run(tmp_path, capsys, MACHINE, "--in-process", "--settle", "0.05", *shadow)
    assert code == 0, err
    record = assert_report(out)
    assert record["mode"] == ("machine in-process shadow" if shadow else "machine in-process")
    assert record["samples"] == record["timing_steps"] > 100
    assert record["timing_sim_time_s"] == pytest.approx(record["simulated_s"])
    assert record["ros_domain"] is None and "ROS domain:           none (in-process" in out
    assert Path(record["bag"]).is_dir() and Path(record["rrd"]).is_file()
    assert "contour error: max " in out and (("shadow x:" in out) == bool(shadow))
