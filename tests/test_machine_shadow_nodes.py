"""The machine's shadow twin as ROS nodes (feed_twin/machine/shadow_nodes.py,
feed_twin/ros/machine_shadow_run.py): per axis a stand-in and a twin node in its own process,
one G-code node and one recorder; every axis's residuals and health equal the in-process machine
shadow's (feed_twin.machine.shadow), and a worn X guide warns on X alone; bad input is refused in
one line before anything starts."""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from nodes_support import last_json, run, start_run
from run_report_support import assert_report
from test_machine_nodes import _child_pid, _simulated_time

from feed_twin.cli import main as cli_main
from feed_twin.io.bag import BagReader
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.shadow import shadow_machine
from feed_twin.ros.domain import reserve_domain_id

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
# X and Z together, about 5.1 s: the health baseline (1.5 s) and the X guide's wear at 2 s fit
PROGRAM = "G90 G54 G17\nG1 X-50 Z-50 F6000\nG1 X50 Z50\nG1 X-50 Z-50\nM2\n"
WEAR_AT_S = 2.0  # [s] the X stand-in's guide friction doubles


def write_machine(directory: Path, edit=None) -> Path:
    """config/machine_default.yaml with X's stand-in wearing at WEAR_AT_S, in `directory`."""
    machine = yaml.safe_load((ROOT / "config" / "machine_default.yaml").read_text())
    shadow = yaml.safe_load(AXIS.read_text())["shadow"]
    shadow["standin"]["friction_steps"] = [{"at_s": WEAR_AT_S, "scale": 2.0}]
    shadow["evaluate_period_s"] = 0.5  # a verdict every 0.5 s: the wear is seen within 1.5 s
    machine["axes"]["X"]["shadow"] = shadow
    if edit is not None:
        edit(machine)
    (directory / "axis_default.yaml").write_text(AXIS.read_text())
    path = directory / "machine.yaml"
    path.write_text(yaml.safe_dump(machine, sort_keys=False))
    return path


@pytest.mark.ros
@pytest.mark.slow
def test_every_axis_shadowed_in_its_own_nodes_equals_the_in_process_shadow(tmp_path):
    config = write_machine(tmp_path)
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = [str(program), "--config", str(config), "--shadow", "--out", str(tmp_path / "out")]
    with reserve_domain_id() as domain:
        code, out, err = run([*argv, "--name", "s", "--json"], domain.domain_id, timeout_s=300)
    assert code == 0, err[-3000:]
    record = assert_report(out, mode="machine nodes shadow")  # the report of every mode
    assert record["processes"] == ["recorder", "x_standin", "x_twin", "y_standin", "y_twin",
                                   "z_standin", "z_twin"]  # fmt: skip
    expected = shadow_machine(load_machine_config(config), program)
    reader = BagReader(record["bag"])
    fields = ["header.stamp", "following_error_measured", "following_error_twin",
              "following_error_deviation", "effort_measured", "effort_twin",
              "effort_deviation"]  # fmt: skip
    for axis, shadow in expected.items():
        a = axis.lower()
        b = shadow.samples
        r = reader.columns(f"/cnc/{a}/twin/residual", fields)
        # the same samples, one per NC period from t = 0: the whole program, each paired once
        assert len(r["header.stamp"]) == len(b.t_s) == record["shadow"][a]["samples"]
        np.testing.assert_allclose(r["header.stamp"], b.t_s, rtol=0, atol=1e-9)
        # both paths run the same core (stand-in engine, ShadowTwin, HealthMonitor) on the same
        # samples; only how many samples each call takes differs, which the cores do not see
        # (1e-15 m / 1e-12 A: rounding, were there any)
        for field, values, atol in (
            ("following_error_measured", b.x_cmd_m - b.x_meas_m, 1e-15),
            ("following_error_twin", b.x_cmd_m - b.x_twin_m, 1e-15),
            ("following_error_deviation", b.fe_dev_m, 1e-15),
            ("effort_measured", b.effort_meas, 1e-12),
            ("effort_twin", b.effort_twin, 1e-12),
            ("effort_deviation", b.effort_dev, 1e-12),
        ):
            np.testing.assert_allclose(r[field], values, rtol=0, atol=atol, err_msg=f"{a} {field}")
        h = reader.columns(f"/cnc/{a}/twin/health", ["header.stamp", "level", "effect"])
        assert list(h["level"]) == [v.level for v in shadow.verdicts], a
        np.testing.assert_allclose(h["header.stamp"], [v.t_s for v in shadow.verdicts], atol=1e-9)
        assert [str(e) for e in h["effect"]] == [v.effect for v in shadow.verdicts], a
        for key, value in shadow.summary().items():
            said = record["shadow"][a][key]
            assert said == (pytest.approx(value, rel=1e-12) if isinstance(value, float) else value)
    shadow = record["shadow"]
    # the worn X guide (+120 N, 0.1 A while moving): X warns within two evaluations after it
    assert shadow["x"]["health"] == "WARN"
    assert WEAR_AT_S < shadow["x"]["first_warning_s"] < WEAR_AT_S + 1.5
    assert shadow["x"]["effect"] and shadow["x"]["message"]
    # Y stands still and Z moves as its nominal model does, up to the stand-in's unmodelled
    # dynamics and noise (config/axis_default.yaml: effort deviation about 0.05 A)
    for a in ("y", "z"):
        assert shadow[a]["health"] == "OK", shadow[a]
        assert shadow[a]["effort_dev_rms"] < 0.06
    assert shadow["y"]["following_error_max_m"] == 0.0
    assert 1e-5 < shadow["z"]["following_error_max_m"] < 1e-3  # the stand-in's Z lags (0.1 mm)
    for a in ("x", "y", "z"):
        assert Path(record["rrd_per_axis"][a]).stat().st_size > 10_000
    assert "shadow x: FE deviation RMS" in out


@pytest.mark.ros
@pytest.mark.slow
def test_a_killed_twin_stops_the_run_naming_its_axis_and_the_bag_stays_readable(tmp_path):
    program = tmp_path / "long.ngc"
    program.write_text("G90 G54\n" + "G1 X-50 Z-50 F3000\nG1 X50 Z50\n" * 3 + "M2\n")  # about 18 s
    argv = [str(program), "--config", str(write_machine(tmp_path)), "--shadow", "--axes", "X,Z",
            "--out", str(tmp_path), "--name", "k", "--json"]  # fmt: skip
    with reserve_domain_id() as domain:
        proc = start_run(argv, domain.domain_id)
        try:
            deadline = time.monotonic() + 180.0
            while _simulated_time(tmp_path / "k.logs" / "x_standin.log") < 0.3:
                assert proc.poll() is None and time.monotonic() < deadline, proc.poll()
                time.sleep(0.1)
            os.kill(_child_pid(proc.pid, "z_twin"), signal.SIGKILL)
            killed_at = time.time()
            out, err = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    record = last_json(out)
    assert record["exit_code"] == 137, err[-3000:]
    assert record["reason"].startswith("axis Z: z_twin node was killed by SIGKILL"), record
    # readable, and X's shadow stopped within a second of the kill, long before the end
    residual = BagReader(record["bag"]).columns("/cnc/x/twin/residual", ["header.stamp"])
    assert residual["log_time_s"][-1] - killed_at < 1.0
    assert 0.3 <= residual["header.stamp"][-1] < 6.0


def _no_shadow_on_y(machine: dict) -> None:
    plant = yaml.safe_load(AXIS.read_text())
    machine["axes"]["Y"] = {k: plant[k] for k in ("plant", "engine", "controller")}


def _shadow_period(machine: dict) -> None:
    machine["axes"]["X"]["shadow"]["sample_period_s"] = 0.002


@pytest.mark.parametrize(
    ("edit", "extra", "message"),
    [
        (_no_shadow_on_y, (), r"machine.yaml: axes.Y: axis Y: no shadow: section \(the shadow "
                              r"twin's limits and its stand-in\)$"),
        (_shadow_period, (), r"axis_default.yaml \(axes.X of .*machine.yaml\): "
                             r"shadow.sample_period_s = 0.002: must equal "
                             r"nc.interpolation_period_s = 0.001 \(the twin shadows the NC's "
                             r"command stream\)$"),
        (None, ("--realtime",), r"--realtime: not available for a machine's shadow node set$"),
    ],
)  # fmt: skip
def test_bad_input_is_refused_in_one_line_before_any_node_starts(
    tmp_path, capsys, edit, extra, message
):
    config = write_machine(tmp_path, edit)
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = ["run", str(program), "--config", str(config), "--shadow", "--out", str(tmp_path)]
    code = cli_main([*argv, "--name", "bad", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and re.search(message, err[0]), err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "bad.logs").exists()
