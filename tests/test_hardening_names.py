"""Issue 29, the inputs around a run: run names stay inside --out and never overwrite an earlier
run, `diagnose --out` keeps an earlier report, argument errors are one line, a header-only CSV
says so, an FMU export on a full disk leaves nothing behind, a read-only --out of a machine run
exits 1, and the reach check counts the weight a vertical axis carries."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import yaml

from feed_twin.cli import main as cli_main
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import MeasuredDataError, read_csv_table
from feed_twin.machine.config import load_machine_config
from feed_twin.nodeset.reach import capability, check_reachable
from feed_twin.ros.preflight import run_name

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
MACHINE = ROOT / "config" / "machine_default.yaml"
NOMINAL = ROOT / "config" / "emps_nominal.yaml"
PROGRAM = "G21 G90\nG1 X1 Z1 F3000\nM2\n"


def _program(tmp_path: Path) -> Path:
    path = tmp_path / "p.ngc"
    path.write_text(PROGRAM)
    return path


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    return err.strip()


@pytest.mark.parametrize("name", ["../../escaped", "a/b", "..", ".", "/abs"])
@pytest.mark.parametrize("config", [AXIS, MACHINE])
def test_a_run_name_that_is_a_path_is_one_line_and_writes_nothing(tmp_path, capsys, name, config):
    out = tmp_path / "deep" / "out"
    mode = "--in-process" if config == MACHINE else "--single-process"
    code = cli_main(["run", str(_program(tmp_path)), "--config", str(config), "--out", str(out),
                     "--name", name, mode])  # fmt: skip
    assert code == 1
    assert _one_line(capsys) == (
        f"feed-twin run: --name {name!r}: must be a file name inside --out, not a path (no '/', "
        "not '.' or '..')"
    )
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["p.ngc"]


@pytest.mark.parametrize("config", [AXIS, MACHINE])
def test_a_name_used_in_out_is_refused_before_anything_starts(tmp_path, capsys, config):
    out = tmp_path / "out"
    (out / "m").mkdir(parents=True)
    (out / "m" / "m_0.mcap").write_bytes(b"earlier bag")
    (out / "m.rrd").write_bytes(b"earlier dashboard")
    code = cli_main(["run", str(_program(tmp_path)), "--config", str(config), "--out", str(out),
                     "--name", "m", "--json"])  # fmt: skip
    assert code == 1
    captured = capsys.readouterr()
    said = f"--name m: already used in {out} (m, m.rrd); choose another name or --out, nothing "
    assert captured.err.strip() == f"feed-twin run: {said}was started"
    # the run report of a refused run, then the same object as the --json line
    said_json = json.loads(captured.out.strip().splitlines()[-1])
    assert said_json["exit_code"] == 1
    assert said_json["reason"].startswith("--name m: already used")
    assert (out / "m" / "m_0.mcap").read_bytes() == b"earlier bag"
    assert (out / "m.rrd").read_bytes() == b"earlier dashboard"
    assert sorted(p.name for p in out.iterdir()) == ["m", "m.rrd"]


def test_a_default_name_taken_in_the_same_second_gets_a_suffix(tmp_path):
    assert run_name(tmp_path, None, "part", "20260101_000000") == "part_20260101_000000"
    (tmp_path / "part_20260101_000000.logs").mkdir()
    (tmp_path / "part_20260101_000000_2").mkdir()
    assert run_name(tmp_path, None, "part", "20260101_000000") == "part_20260101_000000_3"
    assert run_name(tmp_path, "fresh", "part", "x") == "fresh"
    with pytest.raises(ConfigError, match=r"^--name '' : |^--name '': must be a file name"):
        run_name(tmp_path, "", "part", "x")
    with pytest.raises(ConfigError, match=r"longer than 200 bytes"):
        run_name(tmp_path, "n" * 201, "part", "x")


def test_a_read_only_out_of_a_machine_run_exits_1(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code = cli_main(["run", str(_program(tmp_path)), "--config", str(MACHINE), "--in-process",
                     "--out", str(blocker / "out"), "--name", "m"])  # fmt: skip
    assert code == 1
    assert _one_line(capsys) == (
        f"feed-twin run: --out {blocker / 'out'}: cannot create it (Not a directory)"
    )


@pytest.mark.parametrize(
    "argv, said",
    [
        (["run", "p.ngc", "--bogus"], "feed-twin run: unrecognized arguments: --bogus"),
        (["run", "p.ngc", "--max-time", "abc"],
         "feed-twin run: argument --max-time: invalid float value: 'abc'"),
        (["diagnose"], "feed-twin diagnose: the following arguments are required: measured, "
         "--config, --out"),
        (["nosuch"], "feed-twin: unknown command 'nosuch'; choose from"),
    ],
)  # fmt: skip
def test_argument_errors_are_one_line(capsys, argv, said):
    with pytest.raises(SystemExit) as ended:
        cli_main(argv)
    assert ended.value.code == 2
    line = _one_line(capsys)
    assert line.startswith(said) and line.endswith("--help)"), line


def test_diagnose_keeps_an_earlier_report(tmp_path, capsys):
    out = tmp_path / "report"
    out.mkdir()
    (out / "report.md").write_text("earlier")
    code = cli_main(["diagnose", "x.csv", "--config", str(NOMINAL), "--out", str(out)])
    assert code == 2
    assert _one_line(capsys) == (
        f"feed-twin diagnose: --out {out}: holds a report already (report.md); choose another "
        "directory, nothing was written"
    )
    assert (out / "report.md").read_text() == "earlier"
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]


def test_a_header_only_csv_says_so_without_a_numpy_warning(tmp_path):
    path = tmp_path / "h.csv"
    path.write_text("t,q,u,ref,x\n\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(MeasuredDataError) as error:
            read_csv_table(path)
    assert str(error.value) == (
        f"{path}: has a header (5 columns) but no data rows; export the record with its samples"
    )


def _tmpfs(path: Path, size: str):
    path.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], check=True)


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs needs root")
def test_fmu_on_a_full_disk_leaves_nothing(tmp_path):
    small = tmp_path / "small"
    _tmpfs(small, "200k")
    try:
        ended = subprocess.run(
            [sys.executable, "-m", "feed_twin.cli", "fmu", "--config", str(AXIS), "--out",
             str(small / "a.fmu")],
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert ended.returncode == 2
        assert len(ended.stderr.splitlines()) == 1, ended.stderr
        assert "No space left on device" in ended.stderr
        assert list(small.iterdir()) == []
    finally:
        subprocess.run(["umount", str(small)], check=True)


def _heavy_machine(tmp_path: Path, m_kg: float) -> Path:
    raw = yaml.safe_load(MACHINE.read_text())
    for entry in raw["axes"].values():
        entry["include"] = str(AXIS)
    raw["axes"]["Z"]["vertical"]["m_kg"] = m_kg
    path = tmp_path / "heavy.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_the_reach_check_holds_the_weight_of_a_vertical_axis(tmp_path, capsys):
    machine = load_machine_config(_heavy_machine(tmp_path, 6000.0))
    nc = dataclasses.replace(machine.nc, twin_axis="Z")
    z = machine.axes["Z"]
    cap = capability(z, (0.0, 0.5))
    assert cap is not None
    # weight less the 1500 N counterbalance, the load the drive holds at rest
    assert cap.F_static_N == pytest.approx(6000.0 * 9.80665 - 1500.0)
    with pytest.raises(ConfigError, match=r"holding a static load of 57340 N: weight less "):
        check_reachable(z, nc, None, source="m")
    # the default Z (202 kg, 1500 N balanced) is within reach; X carries no weight
    default = load_machine_config(MACHINE)
    check_reachable(default.axes["Z"], nc, None, source="m")
    cap_x = capability(default.axes["X"])
    assert cap_x is not None, "the default X has a controller and a screw: a capability"
    assert cap_x.F_static_N == 0.0
    code = cli_main(["run", str(_program(tmp_path)), "--config", str(tmp_path / "heavy.yaml"),
                     "--in-process", "--out", str(tmp_path / "o"), "--name", "h"])  # fmt: skip
    assert code == 1
    assert "axis Z: nc.axes[Z].rapid_m_s = 0.35: accelerating" in _one_line(capsys)
    assert not (tmp_path / "o" / "h").exists()


def test_a_gas_spring_is_judged_at_the_worst_end_of_the_travel(tmp_path):
    raw = yaml.safe_load(MACHINE.read_text())
    for entry in raw["axes"].values():
        entry["include"] = str(AXIS)
    raw["axes"]["Z"]["vertical"]["counterbalance"] = {
        "type": "gas_spring", "f_N": 1500.0, "s_0_m": 0.25, "k_N_m": 600.0,
    }  # fmt: skip
    path = tmp_path / "gas.yaml"
    path.write_text(yaml.safe_dump(raw))
    z = load_machine_config(path).axes["Z"]
    weight = 202.0 * 9.80665
    # at s = 0.5 the spring pushes 1500 - 600 * 0.25 = 1350 N: the largest net load
    cap = capability(z, (0.0, 0.5))
    assert cap is not None, "the default Z has a controller and a screw: a capability"
    assert cap.F_static_N == pytest.approx(weight - 1350.0)
