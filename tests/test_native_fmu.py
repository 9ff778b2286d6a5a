"""The FMU export checked by an independent importer (FMPy): valid, and simulating it gives the
engine's own result; bad inputs and steps give an FMI error with a message, never a crash."""

from __future__ import annotations

import ctypes
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.model_description import ScalarVariable
from fmpy.validation import validate_fmu
from native_support import ROOT, SAMPLE

from feed_twin.cli import main as cli_main
from feed_twin.native.fmu import fmi_headers
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.program import simulate_program

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
    assert _start(by_name["table.m"]) == 200.0
    assert by_name["controller.Kv_1_s"].unit == "1/s"
    assert _start(by_name["controller.Kv_1_s"]) == 30.0
    assert by_name["controller.m_per_rad"].unit == "m/rad"


def test_fmpy_stepping_equals_simulate_program_to_the_bit(axis_fmu):
    # the same program from the same start state: at every communication point (NC sample j,
    # its command set) the FMU's states, sensor samples and controller outputs are the bits
    # simulate_program records at tick j dec
    axis = load_axis_config(AXIS)
    n = round(SECONDS / 1e-3)
    outputs = (*axis.plant.state_names, "meas.x_scale_m", "meas.i_a_meas_A", "out.i_q_ref_A")
    outputs += ("out.following_error_m", "out.pos_ref_m")
    run = simulate_program(axis, SAMPLE, settle_s=0.0, preroll_s=0.0, record=outputs)
    recorded = run.signals["X"]
    messages: list[str] = []
    start = float(run.command[0, 0])
    slave, vr = _slave(axis_fmu, messages, {"start.table": start})
    names = ("ref.pos_ref_m", "ref.vel_ref_m_s", "ref.acc_ref_m_s2")
    got = np.empty((n, len(outputs)))
    for j in range(n):
        command = (run.command[j, 0], run.command_vel[j, 0], run.command_acc[j, 0])
        slave.setReal([vr[name] for name in names], list(command))
        got[j] = slave.getReal([vr[name] for name in outputs])
        slave.doStep(j * 1e-3, 1e-3)
    slave.terminate()
    slave.freeInstance()
    for i, name in enumerate(outputs):
        assert np.array_equal(got[:, i], recorded[name][:n]), name
    assert np.ptp(got[:, 0]) > 0.3  # the motor turned
    assert messages == []


def _start(variable: ScalarVariable) -> float:
    assert variable.start is not None, f"{variable.name}: no start value"
    return float(variable.start)


def _slave(fmu, messages, parameters=None):
    md = read_model_description(str(fmu))
    assert md.coSimulation is not None, f"{fmu}: not a co-simulation FMU"
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


@pytest.mark.parametrize("name", ["table.m", "max_step", "start.table", "controller.Kv_1_s"])
def test_a_fixed_parameter_is_refused_after_initialisation(axis_fmu, name):
    messages: list[str] = []
    slave, vr = _slave(axis_fmu, messages)
    with pytest.raises(Exception, match="fmi2SetReal failed with status 3"):
        slave.setReal([vr[name]], [0.5])
    assert messages[-1] == f"fmi2SetReal: {name} is a fixed parameter, set before initialisation"
    slave.freeInstance()


@pytest.mark.parametrize(
    ("name", "value", "rule"),
    [
        ("table.m", -5.0, "> 0 kg and finite"),
        ("table.m", 0.0, "> 0 kg and finite"),
        ("motor.L_d", 0.0, "> 0 H and finite"),
        ("motor.p", 0.0, "a whole number >= 1"),
        ("motor.p", 2.5, "a whole number >= 1"),
        ("bus.u_0", -560.0, "> 0 V and finite"),
        ("scale.delay_ticks", 1e9, ">= 0 and <= 63"),  # a fraction of a tick interpolates
        ("scale.delay_ticks", 63.5, ">= 0 and <= 63"),
        ("guides.F_c_pos", -1.0, ">= 0 N and finite"),
        ("screw_shaft.k_t", 0.0, "> 0 N m/rad"),
        ("max_step", 0.0, "> 0 s and finite"),
    ],
)
def test_a_non_physical_parameter_is_an_fmi_error_naming_its_range(axis_fmu, name, value, rule):
    # the ranges are the components' own constructor checks (feed_twin.plant.slot_specs)
    messages: list[str] = []
    with pytest.raises(Exception, match="fmi2SetReal failed with status 3"):
        _slave(axis_fmu, messages, {name: value})
    assert messages[-1] == f"fmi2SetReal: {name} = {value:g}: must be {rule}"


def test_every_parameter_has_a_unit_and_its_range_in_the_model_description(axis_fmu):
    md = read_model_description(str(axis_fmu))
    parameters = [v for v in md.modelVariables if v.causality == "parameter"]
    assert [v.name for v in parameters if not v.unit] == []
    by_name = {v.name: v for v in md.modelVariables}
    for name, unit in [
        ("screw_shaft.k_t", "N m/rad"),
        ("screw_shaft.J", "kg m^2"),
        ("axial.EA", "N"),
        ("encoder.step", "rad"),
        ("controller.effort_limit", "A"),
        ("controller.vel_Kp", "A s/m"),
        ("motor.p", "1"),
    ]:
        assert by_name[name].unit == unit, name
    delay = by_name["scale.delay_ticks"]
    assert (delay.min, delay.max) == ("0.0", "63.0")
    assert by_name["table.m"].description == "> 0 kg and finite"


def test_the_sources_compile_clean_as_c99_without_hidden_warnings(axis_fmu, tmp_path):
    unzipped = Path(extract(str(axis_fmu), unzipdir=str(tmp_path / "fmu")))
    sources = sorted((unzipped / "sources").glob("*.c"))
    assert [p.name for p in sources] == ["feed_twin_axis.c", "fmu_glue.c"]
    for path in sources:
        assert "#pragma" not in path.read_text(), path.name
        flags = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-fsyntax-only"]
        includes = ["-I", str(fmi_headers()), "-I", str(unzipped / "sources")]
        done = subprocess.run(["cc", *flags, *includes, str(path)], capture_output=True, text=True)
        assert (done.returncode, done.stderr) == (0, ""), path.name


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


def test_libcosim_runs_the_fmu_to_the_bits_of_simulate_program(axis_fmu):
    # a second importer (libcosim, on the FMI Library): the program's commands through its
    # override manipulator, one 1 ms step each; after step j the states and sensor samples are
    # those simulate_program records at the next NC sample
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    axis = load_axis_config(AXIS)
    n = 300
    outputs = (*axis.plant.state_names, "meas.x_scale_m", "meas.theta_enc_rad")
    run = simulate_program(axis, SAMPLE, settle_s=0.0, preroll_s=0.0, record=outputs)
    execution = CosimExecution.from_step_size(step_size=1_000_000)  # [ns]
    slave = CosimLocalSlave(fmu_path=str(axis_fmu), instance_name="axis")
    index = execution.add_local_slave(local_slave=slave)
    vr = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer=observer)
    override = CosimManipulator.create_override()
    execution.add_manipulator(manipulator=override)
    execution.real_initial_value(index, vr["start.table"], float(run.command[0, 0]))
    names = ("ref.pos_ref_m", "ref.vel_ref_m_s", "ref.acc_ref_m_s2")
    got = np.empty((n, len(outputs)))
    for j in range(n):
        command = [run.command[j, 0], run.command_vel[j, 0], run.command_acc[j, 0]]
        override.slave_real_values(index, [vr[name] for name in names], command)
        assert execution.step(step_count=1)
        got[j] = observer.last_real_values(index, [vr[name] for name in outputs])
    for i, name in enumerate(outputs):
        assert np.array_equal(got[:, i], run.signals["X"][name][1 : n + 1]), name
    assert np.ptp(got[:, outputs.index("table.s")]) > 1e-3  # it moved
