"""`feed-twin simulate` / `diagnose` on the command line, and their error messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.fit import FreeParameter, Measured, SimOutputs, fit
from feed_twin.cli import main

ROOT = Path(__file__).resolve().parents[1]
EMPS = Path("/work/shared/data/emps")
NOMINAL = ROOT / "config" / "emps_nominal.yaml"
MAP = ROOT / "config" / "emps_map.yaml"


def test_simulate_writes_measured_and_sim_columns(tmp_path, capsys):
    out = tmp_path / "traces.csv"
    code = main(
        [
            "simulate",
            "--config",
            str(NOMINAL),
            "--measured",
            str(EMPS / "DATA_EMPS_PULSES.csv"),
            "--map",
            str(MAP),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header[0] == "t_s"
    for name in ("pos_cmd_m", "pos_meas_m", "force_cmd_N", "disturbance_effort_add_N"):
        assert name in header and f"sim_{name}" in header
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    col = {n: data[:, i] for i, n in enumerate(header)}
    # the nominal twin tracks the measured position to a few hundredths of a percent
    err = np.linalg.norm(col["pos_meas_m"] - col["sim_pos_meas_m"]) / np.linalg.norm(
        col["pos_meas_m"]
    )
    assert err < 5e-4
    # and without Coulomb friction and offset its force is tens of percent off
    ferr = np.linalg.norm(col["force_cmd_N"] - col["sim_force_cmd_N"]) / np.linalg.norm(
        col["force_cmd_N"]
    )
    assert 0.2 < ferr < 0.6
    assert "wrote" in capsys.readouterr().out


def test_missing_map_is_explained(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    csv.write_text("t,x\n0,0\n")
    code = main(["diagnose", str(csv), "--config", str(NOMINAL), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "no column map given (--map) and no run_map.yaml next to the data" in err


def test_record_without_command_asks_for_the_program(tmp_path, capsys):
    m = tmp_path / "m.yaml"
    m.write_text(MAP.read_text().replace("  pos_cmd_m: {column: qg_ref_m, unit: m}\n", ""))
    code = main(
        [
            "simulate",
            "--config",
            str(NOMINAL),
            "--measured",
            str(EMPS / "DATA_EMPS.csv"),
            "--map",
            str(m),
            "--out",
            str(tmp_path / "t.csv"),
        ]
    )
    assert code == 2
    assert "has no command (pos_cmd_m or vel_cmd_m_s); give the G-code" in capsys.readouterr().err


def test_bad_model_config_is_named(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("plant: {components: [], connect: []}\n")
    code = main(
        [
            "simulate",
            "--config",
            str(bad),
            "--measured",
            str(EMPS / "DATA_EMPS.csv"),
            "--map",
            str(MAP),
            "--out",
            str(tmp_path / "t.csv"),
        ]
    )
    assert code == 2
    assert f"{bad}: missing required section controller" in capsys.readouterr().err


def _line_model(true_slope: float):
    """A stand-in batch simulator: x = slope * t (no plant: the fit logic alone is under test)."""
    t = np.linspace(0.0, 1.0, 200)

    def simulate(params: np.ndarray) -> SimOutputs:
        x = params[:, :1] * t[None, :] ** 2 + params[:, 1:2] * t[None, :]
        return SimOutputs(x_m=x, effort=None, ok=np.ones(len(params), bool))

    meas = Measured(x_m=true_slope * t**2 + 0.5 * t, effort=None, scale_x=1.0, scale_effort=1.0)
    return simulate, meas


def test_fit_recovers_parameters_and_counts_simulations():
    simulate, meas = _line_model(2.0)
    free = [
        FreeParameter(name="a", initial=1.0, scale=1.0),
        FreeParameter(name="b", initial=0.0, scale=1.0),
    ]
    r = fit(simulate, np.zeros(2), {"a": (0,), "b": (1,)}, free, meas)
    assert r.converged
    assert r.values["a"] == pytest.approx(2.0, abs=1e-6)
    assert r.values["b"] == pytest.approx(0.5, abs=1e-6)
    assert r.cost < 1e-12 < r.cost_initial
    assert r.evaluations >= 3  # the Jacobian costs one batch of 2 sets


def test_fit_that_cannot_converge_says_so_and_keeps_the_start():
    t = np.linspace(0.0, 1.0, 50)

    def diverging(params: np.ndarray) -> SimOutputs:
        ok = params[:, 0] < 1.5  # beyond that the "plant" diverges
        x = np.where(ok[:, None], params[:, :1] * t[None, :], np.nan)
        return SimOutputs(x_m=x, effort=None, ok=ok)

    meas = Measured(x_m=3.0 * t, effort=None, scale_x=1.0, scale_effort=1.0)
    free = [FreeParameter(name="a", initial=1.0, scale=1.0)]
    r = fit(diverging, np.zeros(1), {"a": (0,)}, free, meas, max_evaluations=3)
    assert not r.converged
    assert r.values["a"] <= 1.5
    assert math.isfinite(r.cost) and r.cost <= r.cost_initial


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_fit_maps_only_log_parameters_through_exp():
    """A linear parameter far from its scale (a force of 2000 N at scale 1) beside a log one:
    exp(2000) would overflow, so the log map must never be evaluated on a linear slot."""
    t = np.linspace(0.0, 1.0, 100)

    def simulate(params: np.ndarray) -> SimOutputs:
        x = params[:, :1] * t[None, :] + 1.0 / params[:, 1:2] * t[None, :] ** 2
        return SimOutputs(x_m=x, effort=None, ok=np.ones(len(params), bool))

    meas = Measured(x_m=2000.0 * t + 0.25 * t**2, effort=None, scale_x=1.0, scale_effort=1.0)
    free = [
        FreeParameter(name="force", initial=1900.0, scale=1.0),
        FreeParameter(name="stiffness", initial=1.0, scale=1.0, lower=0.0, log=True),
    ]
    r = fit(simulate, np.zeros(2), {"force": (0,), "stiffness": (1,)}, free, meas)
    assert r.values["force"] == pytest.approx(2000.0, abs=1e-4)
    assert r.values["stiffness"] == pytest.approx(4.0, rel=1e-4)


@pytest.mark.slow
def test_command_from_the_program_that_ran(tmp_path):
    from feed_twin.analysis.program import command_from_program
    from feed_twin.analysis.synthetic import NC_CONFIG, PROGRAM, generate, write_csv
    from feed_twin.analysis.twin import ModelDoc
    from feed_twin.io.measured import load_measured

    nominal = ModelDoc.load(NOMINAL)
    cols = generate(nominal, {})
    # the scope started 0.4 s after the program and recorded no command
    start = 400
    cols = {k: v[start:] for k, v in cols.items() if k != "x_cmd_mm"}
    cols["time_ms"] = cols["time_ms"] - cols["time_ms"][0] + 123.0
    map_path = write_csv(tmp_path / "scope.csv", cols, nominal)
    map_path.write_text(
        map_path.read_text().replace("  pos_cmd_m: {column: x_cmd_mm, unit: mm}\n", "")
    )
    run = load_measured(tmp_path / "scope.csv", map_path)
    assert "pos_cmd_m" not in run
    import yaml

    nc = yaml.safe_load(NC_CONFIG)["nc"]
    program = tmp_path / "part.ngc"
    program.write_text(PROGRAM)
    bare = command_from_program(run, program, nc=nc)
    # the bare command comparison is late by the loop lag, about 1/Kv = 6 ms
    assert any("the program starts -0.39" in w for w in bare.warnings), bare.warnings
    with_cmd = command_from_program(run, program, nc=nc, model=nominal)
    assert any("the program starts -0.4000" in w for w in with_cmd.warnings), with_cmd.warnings
    truth = generate(nominal, {})["x_cmd_mm"][start:] * 1e-3
    # aligned to a fraction of a sample: the setpoint error stays below v_max * 0.1 ms
    assert np.max(np.abs(with_cmd["pos_cmd_m"] - truth)) < 0.12 * 1e-4


def test_record_period_that_does_not_fit_the_model_is_explained(tmp_path, capsys):
    raw = np.genfromtxt(EMPS / "DATA_EMPS.csv", delimiter=",", skip_header=1)[:2000]
    raw[:, 0] *= 1.5  # a 1.5 ms record against the bench's 1 ms controller
    csv = tmp_path / "slow.csv"
    np.savetxt(csv, raw, delimiter=",", header="t_s,qg_ref_m,qm_meas_m,vir_ctrl_V,force_motor_N",
               comments="")  # fmt: skip
    code = main(["simulate", "--config", str(NOMINAL), "--measured", str(csv), "--map", str(MAP),
                 "--out", str(tmp_path / "t.csv")])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert (
        "sample period 0.0015" in err and "not a whole multiple of the model's base period" in err
    )


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"max_effects": 0}, r"max_effects = 0: must be a whole number >= 1"),
        ({"max_evaluations": 2.5}, r"max_evaluations = 2.5: must be a whole number >= 1"),
        ({"rival_ratio": 0.0}, r"rival_ratio = 0.0: must lie in \(0, 1\]"),
    ],
)
def test_bad_workflow_options_are_named(change, message):
    from feed_twin.analysis.diagnose import Options

    with pytest.raises(ValueError, match=message):
        Options(**change)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scale": 0.0}, r"a: scale = 0.0: must be > 0"),
        ({"lower": 2.0, "upper": 1.0}, r"a: bounds \[2.0, 1.0\]: lower must be < upper"),
        ({"initial": float("nan")}, r"a: initial = nan: must be finite"),
    ],
)
def test_bad_free_parameter_is_named(kwargs, message):
    spec = {"name": "a", "initial": 1.0, "scale": 1.0} | kwargs
    with pytest.raises(ValueError, match=message):
        FreeParameter(**spec)


def test_bad_unmodelled_dynamics_are_named():
    from feed_twin.analysis.synthetic import Unmodelled

    with pytest.raises(ValueError, match=r"current_lag_s = -1.0: must be >= 0"):
        Unmodelled(current_lag_s=-1.0)
    with pytest.raises(ValueError, match=r"effort_noise_std = -0.1: must be >= 0"):
        Unmodelled(effort_noise_std=-0.1)
    with pytest.raises(ValueError, match=r"sensor_seed = -2: must be >= 0"):
        Unmodelled(sensor_seed=-2)


def test_diagnose_runs_with_one_blas_thread_unless_the_user_set_one():
    """`feed-twin diagnose` sets OPENBLAS_NUM_THREADS before numpy loads OpenBLAS (OpenBLAS
    reads it once, at load): the CLI's registry imports nothing numeric first."""
    import os
    import subprocess
    import sys

    probe = (
        "import sys, importlib, os, feed_twin.cli\n"
        "assert 'numpy' not in sys.modules, 'numpy loaded before the analysis CLI'\n"
        "importlib.import_module('feed_twin.analysis.cli')\n"
        "print(os.environ['OPENBLAS_NUM_THREADS'])\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "1"
    env["OPENBLAS_NUM_THREADS"] = "2"
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True)
    assert out.stdout.strip() == "2", out.stderr
