"""The FMU export checked by an independent importer (FMPy): valid, and simulating it gives the
engine's own result; bad inputs and steps give an FMI error with a message, never a crash."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.validation import validate_fmu
from native_support import ROOT, SAMPLE, program_ref

from feed_twin.cli import main as cli_main
from feed_twin.core import signals
from feed_twin.sim.config import build_engine, load_axis_config

AXIS = ROOT / "config" / "axis_default.yaml"
SECONDS = 2.0  # of sample.ngc: the pocket's first moves


@pytest.fixture(scope="module")
def axis_fmu(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmu") / "axis.fmu"
    assert cli_main(["fmu", "--config", str(AXIS), "--out", str(out)]) == 0
    return out


def test_fmpy_validates_the_model_description(axis_fmu):
    assert validate_fmu(str(axis_fmu)) == []
    md = read_model_description(str(axis_fmu))
    by_name = {v.name: v for v in md.modelVariables}
    assert by_name["table.s"].causality == "output" and by_name["table.s"].unit == "m"
    assert by_name["motor.i_q"].unit == "A"
    assert by_name["out.following_error_m"].unit == "m"
    assert by_name["ref.pos_ref_m"].causality == "input"
    assert by_name["table.m"].causality == "parameter" and by_name["table.m"].unit == "kg"
    assert float(by_name["table.m"].start) == 200.0
    assert by_name["controller.Kv_1_s"].unit == "1/s"
    assert float(by_name["controller.Kv_1_s"].start) == 30.0
    assert by_name["controller.m_per_rad"].unit == "m/rad"


def test_fmpy_simulation_equals_the_engine(axis_fmu):
    axis = load_axis_config(AXIS)
    h = axis.engine.base_period_s
    ref = program_ref(SAMPLE, h)[: round(SECONDS / h)]
    dec = round(1e-3 / h)
    nc = ref[::dec]
    t = np.arange(len(nc)) * 1e-3
    names = ("ref.pos_ref_m", "ref.vel_ref_m_s", "ref.acc_ref_m_s2")
    inputs = np.zeros(len(nc), dtype=[("time", float)] + [(n, float) for n in names])
    inputs["time"] = t
    for name, slot in zip(
        names, (signals.REF_POS_M, signals.REF_VEL_M_S, signals.REF_ACC_M_S2), strict=True
    ):
        inputs[name] = nc[:, slot]
    start = float(ref[0, signals.REF_POS_M])
    result = simulate_fmu(
        str(axis_fmu),
        stop_time=t[-1],
        output_interval=1e-3,
        input=inputs,
        start_values={"start.table": start},
    )
    engine = build_engine(axis, output_period_s=h)
    # the FMU's start state: the state at rest at 1 m, times the start position (the engine's
    # initial_state rounds the ratios in another order; at an encoder count's edge that matters)
    engine.reset(x0=axis.plant.initial_state({"table": 1.0}) * start)
    expected = engine.advance(len(ref), ref=ref)
    rows = np.arange(len(result)) * dec  # the state after k ms is the row of tick 16 k
    for name in axis.plant.state_names:
        got, want = result[name], expected[name][rows]
        span = max(np.abs(want).max(), 1e-300)
        assert np.abs(got - want).max() <= 1e-12 * span, name
    # meas and out after a step are those of its last tick
    fe = result["out.following_error_m"][1:]
    assert np.array_equal(fe, expected["out.following_error_m"][rows[1:] - 1])
    assert np.ptp(result["table.s"]) > 0.03


def _slave(fmu, messages, parameters=None):
    md = read_model_description(str(fmu))
    slave = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(str(fmu)),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="test",
    )

    def log(env, name, status, category, message, *args):
        messages.append(message.decode())

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(log)
    from fmpy.logging import addLoggerProxy

    addLoggerProxy(ctypes.byref(callbacks))
    slave.instantiate(callbacks=callbacks)
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    refs = {v.name: v.valueReference for v in md.modelVariables}
    for name, value in (parameters or {}).items():
        slave.setReal([refs[name]], [value])
    slave.exitInitializationMode()
    return slave, refs


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_input_is_an_fmi_error_with_a_message(axis_fmu, value):
    messages: list[str] = []
    slave, vr = _slave(axis_fmu, messages)
    with pytest.raises(Exception, match="fmi2SetReal failed with status 3"):
        slave.setReal([vr["ref.pos_ref_m"]], [value])
    assert messages[-1] == f"fmi2SetReal: ref.pos_ref_m = {value!r} is not finite"
    slave.doStep(0.0, 1e-3)  # the instance still works
    slave.terminate()
    slave.freeInstance()


@pytest.mark.parametrize(
    ("step", "message"),
    [
        (2.0, "fmi2DoStep: step 2 s at t = 0 s: must be > 0 and <= max_step = 1 s"),
        (1e-4, "fmi2DoStep: step 0.0001 s is not a whole number of base periods (6.25e-05 s)"),
    ],
)
def test_a_step_the_model_does_not_allow_is_an_fmi_error(axis_fmu, step, message):
    messages: list[str] = []
    slave, _ = _slave(axis_fmu, messages)
    with pytest.raises(Exception, match="fmi2DoStep failed with status 3"):
        slave.doStep(0.0, step)
    assert messages[-1] == message
    slave.freeInstance()


def test_fmu_cli_names_a_bad_output_name(tmp_path, capsys):
    assert cli_main(["fmu", "--config", str(AXIS), "--out", str(tmp_path / "axis.zip")]) == 2
    assert capsys.readouterr().err.strip().endswith("axis.zip: must end in .fmu")


def test_a_runaway_state_is_an_fmi_error_naming_the_state(axis_fmu):
    # a coupling 1e5 times stiffer than configured: RK4 at 62.5 us is unstable for it
    messages: list[str] = []
    slave, vr = _slave(axis_fmu, messages, {"coupling.k": 1e12})
    with pytest.raises(Exception, match="fmi2DoStep failed with status 3"):
        slave.doStep(0.0, 1e-3)
    assert messages[-1].startswith("fmi2DoStep: the state motor.omega ran away at t = ")
    slave.freeInstance()


def test_a_fixed_parameter_is_refused_after_initialisation(axis_fmu):
    messages: list[str] = []
    slave, vr = _slave(axis_fmu, messages)
    with pytest.raises(Exception, match="fmi2SetReal failed with status 3"):
        slave.setReal([vr["table.m"]], [150.0])
    assert messages[-1] == "fmi2SetReal: table.m is a fixed parameter, set before initialisation"
    slave.freeInstance()


def test_the_fmu_rebuilt_from_its_sources_by_fmpy_gives_the_same_result(tmp_path):
    # sources/ carries everything: FMPy's own CMake build of it replaces the binary
    from fmpy.build import build_platform_binary

    fmu = tmp_path / "emps.fmu"
    assert cli_main(["fmu", "--config", str(ROOT / "config" / "emps.yaml"), "--out", str(fmu)]) == 0
    ramp = np.zeros(201, dtype=[("time", float), ("ref.pos_ref_m", float)])
    ramp["time"] = np.arange(201) * 1e-3
    ramp["ref.pos_ref_m"] = 0.02 * ramp["time"]
    shipped = simulate_fmu(str(fmu), stop_time=0.2, output_interval=1e-3, input=ramp)
    unzipped = tmp_path / "unzipped"
    extract(str(fmu), unzipdir=str(unzipped))
    library = unzipped / "binaries" / "linux64" / "feed_twin_axis.so"
    library.unlink()
    build_platform_binary(unzipped)
    assert library.exists()
    rebuilt = simulate_fmu(str(unzipped), stop_time=0.2, output_interval=1e-3, input=ramp)
    assert np.array_equal(rebuilt["table.s"], shipped["table.s"])
    assert shipped["table.s"][-1] > 1e-3  # it moved
