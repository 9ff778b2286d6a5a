"""`feed-twin run PROGRAM --config MACHINE.yaml --nc linuxcnc --shadow`: the real LinuxCNC plans
the program and its simulated servo loops are the machine; one bridge node publishes every
joint, a twin node per axis shadows it, one recorder records all axes (one run, about 20 s
wall); a machine LinuxCNC cannot be is refused in one line before anything starts."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from nodes_support import run
from run_report_support import assert_report

from feed_twin.cli import main as cli_main
from feed_twin.io.bag import BagReader
from feed_twin.io.bag.counts import mcap_counts
from feed_twin.linuxcnc.host import leftovers
from feed_twin.ros.domain import reserve_domain_id

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
AXIS = ROOT / "config" / "axis_default.yaml"
# from the start (G54 X0 Y0 Z150) a short diagonal, then three of (+-40, -+20, +-10) mm at
# F6000: about 2 s, so the twins' health baseline (1.5 s) completes
PROGRAM = "G90 G54 G17\nG1 X-20 Y10 Z140 F6000\n" + "G1 X20 Y-10 Z150\nG1 X-20 Y10 Z140\n" * 2
PROGRAM += "M2\n"
F_M_S = 0.1  # F6000 mm/min
LONG = math.hypot(40.0, 20.0, 10.0)  # [mm] moves 2-4
SHORT = math.hypot(20.0, 10.0, 10.0)  # [mm] move 1


def write_mill(directory: Path, edit=None) -> Path:
    """config/machine_default.yaml without its rotary table (LinuxCNC's mill is X, Y, Z)."""
    machine = yaml.safe_load(MACHINE.read_text())
    del machine["nc"]["rotary_axes"]
    if edit is not None:
        edit(machine)
    (directory / "axis_default.yaml").write_text(AXIS.read_text())
    path = directory / "mill.yaml"
    path.write_text(yaml.safe_dump(machine, sort_keys=False))
    return path


@pytest.mark.ros
def test_every_axis_of_linuxcnc_is_shadowed_by_its_own_twin(tmp_path: Path) -> None:
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = [str(program), "--config", str(write_mill(tmp_path)), "--nc", "linuxcnc",
            "--shadow", "--out", str(tmp_path / "out"), "--name", "l", "--json"]  # fmt: skip
    with reserve_domain_id() as domain:
        code, out, err = run(argv, domain.domain_id, timeout_s=300)
    assert code == 0, err[-3000:]
    record = assert_report(out, mode="machine LinuxCNC shadow")  # the report of every mode
    assert record["processes"] == ["recorder", "linuxcnc", "x_twin", "y_twin", "z_twin"]
    # the bridge and every twin ran with a larger share of the CPU (ros.linuxcnc_nice), or said
    # why not (`scheduling: nice -10 refused (...)`)
    for process in record["processes"][1:]:
        log = (tmp_path / "out" / "l.logs" / f"{process}.log").read_text()
        assert "scheduling: nice -10" in log, process
    bridge = record["linuxcnc"]
    assert bridge["samples_lost"] == 0
    # every axis's topics counted against what the bridge published, and the counts are the
    # bag's as the mcap library reads them (the bridge sends them packed: linuxcnc_node)
    expected = {f"/cnc/{a}/{t}" for a in "xyz" for t in ("command", "joint_states",
                "twin/residual", "twin/state")} | {"/cnc/x/linuxcnc/servo"}  # fmt: skip
    assert set(bridge["samples_lost_by_topic"]) == expected
    assert not any(bridge["samples_lost_by_topic"].values())
    counts = mcap_counts(Path(record["bag"]))
    assert bridge["bag_counts"] == {topic: counts[topic] for topic in expected}
    reader = BagReader(record["bag"])
    fields = [f"{name}[{j}]" for name in ("following_error", "velocity_command") for j in range(3)]
    servo = reader.columns("/cnc/x/linuxcnc/servo", ["header.stamp", *fields])
    n = len(servo["header.stamp"])
    assert n == bridge["samples_published"] >= bridge["program_time_s"] / 1e-3
    # the programmed feed along each move, split over the axes (cruise at F on every move)
    peak = {"x": F_M_S * 40.0 / LONG, "y": F_M_S * 20.0 / LONG, "z": F_M_S * 10.0 / SHORT}
    for j, axis in enumerate(("x", "y", "z")):
        command = reader.columns(f"/cnc/{axis}/command", ["header.stamp", "velocity"])
        joints = reader.columns(f"/cnc/{axis}/joint_states", ["header.stamp"])
        residual = reader.columns(
            f"/cnc/{axis}/twin/residual", ["header.stamp", "following_error_measured"]
        )
        # every servo period of the joint published, its feedback one period later, and every
        # feedback shadowed by the axis's twin
        assert len(command["header.stamp"]) == n
        assert len(joints["header.stamp"]) == n - 1
        assert len(residual["header.stamp"]) == n - 1 == record["shadow"][axis]["samples"]
        np.testing.assert_allclose(residual["header.stamp"], servo["header.stamp"][:-1], atol=1e-9)
        assert np.abs(command["velocity"]).max() == pytest.approx(peak[axis], rel=1e-4)
        assert np.abs(servo[f"velocity_command[{j}]"]).max() == pytest.approx(peak[axis], rel=1e-4)
        # two paths to LinuxCNC's following error of this joint: the twin's pairing of the
        # command and feedback streams (slot k - 1) and LinuxCNC's own f-error pin (period k);
        # mm -> m rounding only
        np.testing.assert_allclose(
            residual["following_error_measured"],
            servo[f"following_error[{j}]"][1:],
            rtol=0.0,
            atol=1e-12,
            err_msg=axis,
        )
        figures = record["shadow"][axis]
        assert figures["linuxcnc_following_error_max_m"] == pytest.approx(
            figures["following_error_max_m"], abs=1e-12
        )
        assert 1e-6 < figures["following_error_max_m"] < 1e-3
        assert figures["effort_dev_rms"] is None  # the HAL servo reports no effort
        assert 0.0 < figures["fe_dev_rms_m"] < 1e-3
        assert figures["health"] in ("OK", "WARN", "ERROR")
        assert Path(record["rrd_per_axis"][axis]).stat().st_size > 10_000
    assert leftovers() == []


def _slower_z_loop(machine: dict) -> None:
    axis = yaml.safe_load(AXIS.read_text())
    axis["controller"]["position"]["Kv_1_s"] = 20.0
    z = machine["axes"]["Z"]
    del z["include"]
    z.update({k: axis[k] for k in ("plant", "engine", "controller", "shadow")})


@pytest.mark.parametrize(
    ("config", "extra", "message"),
    [
        (None, ("--shadow",), r"machine_default.yaml: nc: axis B: the LinuxCNC machine \(a "
                              r"3-axis mill, joints X, Y, Z\) has no B; shadow it on a machine "
                              r"config without it$"),
        (_slower_z_loop, ("--shadow",), r"mill.yaml: axes X and Z: their position loops differ "
                                        r"\(Kv 30.0 and 20.0 1/s, following-error limit 0.002 "
                                        r"and 0.002 m\): the LinuxCNC machine has one HAL servo "
                                        r"for every joint$"),
        (False, (), r"--nc linuxcnc runs the program on LinuxCNC with the machine's twins beside "
                    r"it: add --shadow \(without --in-process\)$"),
    ],
)  # fmt: skip
def test_a_machine_linuxcnc_cannot_be_is_refused_in_one_line(
    tmp_path: Path, capsys, config, extra, message
) -> None:
    path = MACHINE if config is None else write_mill(tmp_path, config or None)
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = ["run", str(program), "--config", str(path), "--nc", "linuxcnc", *extra]
    code = cli_main([*argv, "--out", str(tmp_path), "--name", "bad"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and re.search(message, err[0]), err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "bad.logs").exists()
