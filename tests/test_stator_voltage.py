"""The d-axis equation fitted to the stator voltage a drive applied, rebuilt from its references.

The node set's exchanges (ControllerCore + DriveHost, as `Lockstep` runs them), with the drive's
engine replayed beside them recording every current-loop sample: the drive's own trace at 16 kHz.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from nodes_support import AXIS_CONFIG, SHORT_PROGRAM

from feed_twin.analysis.stator_voltage import DriveVoltagePath, applied_stator_voltage, d_axis_fit
from feed_twin.control.layout import enable
from feed_twin.core import signals as sig
from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.nodeset.drive_host import DriveHost, Lockstep, nc_samples
from feed_twin.nodeset.nc_buffer import NcBuffer
from feed_twin.nodeset.wire import drive_reference
from feed_twin.sim.config import build_engine, load_axis_config

JERK_9_MS = "j_max_m_s3: 333.34,\n       travel_min_m: 0.0, travel_max_m: 0.8"  # the X axis
JERK_50_MS = "j_max_m_s3: 60.0,\n       travel_min_m: 0.0, travel_max_m: 0.8"  # 3 m/s^2 / 60
DEAD_TIME = "t_dead: 1.0e-6, u_f: 1.2"
COMPENSATION = "    dead_time_comp_V: 10.16"
CONTROLLER_L_Q = "    L_q_H: 4.0e-3"


def variant(tmp_path: Path, name: str, *edits: tuple[str, str]) -> Path:
    """axis_default.yaml with text edits, each of a text that must be there."""
    text = AXIS_CONFIG.read_text()
    for old, new in edits:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


def current_loop_trace(config: Path, program: Path) -> dict[str, np.ndarray]:
    """Every current-loop sample of the node set's exchanges for the program, by signal name."""
    pair = Lockstep.for_config(config)
    controller, host, ros = pair.controller, pair.host, pair.ros
    axis = load_axis_config(config)
    assert axis.controller is not None
    names = DriveHost.record_names(host.signals)
    trace = build_engine(
        axis,
        closed_loop=True,
        mode=ros.boundary,
        record=names,
        output_period_s=axis.controller.base_period_s,
    )
    trace.reset(positions={"table": host.setpoint.position_m})
    trajectory = plan_program(program, load_nc_config(config))
    x, v, a = trajectory.axis("X")
    buffer = NcBuffer()
    for sample in nc_samples(trajectory.t_s, x, v, a, trajectory.line):
        buffer.add(sample)
    buffer.finish()
    until_ns = round((trajectory.t_s[-1] + ros.settle_s) * 1e9)
    rows, setpoint, reference = [], None, np.zeros((1, sig.REF_SIZE))
    while host.t_ns <= until_ns:
        sample = host.step(setpoint)
        enable(trace.cs)
        drive_reference(host.setpoint, host.K_t, reference[0])
        rows.append(np.array(trace.advance(host.ticks, reference, hold=host.ticks).data))
        # the replay is the exchange: its first sample is what the node set records
        assert rows[-1][0, names.index("out.u_d_ref_V")] == sample.feedback["u_d_ref"]
        t_next = sample.t_ns + host.exchange_ns
        nc = buffer.for_time(t_next)
        assert nc is not None
        setpoint = controller.step(t_next, nc, sample.meas)
    data = np.concatenate(rows)
    return {n: data[:, i] for i, n in enumerate(names)}


def plant_values(config: Path) -> dict[str, float]:
    plant = load_axis_config(config).plant
    return dict(zip(plant.param_names, plant.param_vector().tolist(), strict=True))


def voltage_path(config: Path) -> DriveVoltagePath:
    """The drive's path from reference to terminals as its configuration states it."""
    axis = load_axis_config(config)
    assert axis.controller is not None and axis.controller.current is not None
    current, plant = axis.controller.current, plant_values(config)
    return DriveVoltagePath(
        T_i=axis.controller.base_period_s,
        computation_delay=axis.controller.computation_delay,
        angle_advance_periods=current.angle_advance_periods,
        dead_time_comp_V=current.dead_time_comp_V,
        dead_time_comp_band_A=current.dead_time_comp_band_A,
        t_dead=plant["inverter.t_dead"],
        f_pwm=plant["inverter.f_pwm"],
        u_f=plant["inverter.u_f"],
        i_reg=plant["inverter.i_reg"],
    )


def rebuilt_voltage(
    trace: dict[str, np.ndarray], path: DriveVoltagePath, theta_e: np.ndarray, omega_e: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`applied_stator_voltage` of a trace's references, phase currents and bus."""
    return applied_stator_voltage(
        path,
        u_d_ref=trace["out.u_d_ref_V"],
        u_q_ref=trace["out.u_q_ref_V"],
        theta_e=theta_e,
        omega_e=omega_e,
        i_a=trace["meas.i_a_meas_A"],
        i_b=trace["meas.i_b_meas_A"],
        i_c=trace["meas.i_c_meas_A"],
        u_dc=trace["meas.u_dc_V"],
    )


def drive_fits(config: Path, program: Path) -> tuple[float, float, float]:
    """(L_q of the rebuilt stator voltage, L_q of the references themselves, motor's L_q) [H],
    from the drive's own signals only: references, latched phase currents, encoder, bus."""
    trace = current_loop_trace(config, program)
    controller = load_axis_config(config).controller
    assert controller is not None and controller.current is not None
    theta_e = controller.current.pole_pairs * np.unwrap(trace["meas.theta_enc_rad"])
    path = voltage_path(config)
    omega_e = np.gradient(theta_e, path.T_i)
    i_a, i_b, i_c = (trace[f"meas.i_{x}_meas_A"] for x in "abc")
    u_d, _ = rebuilt_voltage(trace, path, theta_e, omega_e)
    i_alpha, i_beta = (2.0 * i_a - i_b - i_c) / 3.0, (i_b - i_c) / np.sqrt(3.0)
    i_d = np.cos(theta_e) * i_alpha + np.sin(theta_e) * i_beta
    i_q = -np.sin(theta_e) * i_alpha + np.cos(theta_e) * i_beta
    from_voltage = d_axis_fit(u_d, i_d, i_q, omega_e, path.T_i).L_q
    references = d_axis_fit(trace["out.u_d_ref_V"], i_d, i_q, omega_e, path.T_i).L_q
    return from_voltage, references, plant_values(config)["motor.L_q"]


@pytest.fixture(scope="module")
def program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("stator") / "move.ngc"
    path.write_text(SHORT_PROGRAM)
    return path


def test_the_fit_is_exact_where_the_references_are_the_stator_voltage(
    tmp_path: Path, program: Path
) -> None:
    # dead time and its compensation off, the computation delay's turn advanced by the drive
    # (1.5 periods): the rebuilt voltage is the reference, and the motor's equation holds for
    # it at every current-loop sample, with the motor's own currents and speed
    config = variant(
        tmp_path, "exact", (DEAD_TIME, "t_dead: 0.0, u_f: 0.0"),
        (COMPENSATION, "    angle_advance_periods: 1.5\n    dead_time_comp_V: 0.0"),
    )  # fmt: skip
    trace = current_loop_trace(config, program)
    path = voltage_path(config)
    p = plant_values(config)["motor.p"]
    theta_e, omega_e = p * trace["meas.theta_enc_rad"], p * trace["motor.omega"]
    u_d, u_q = rebuilt_voltage(trace, path, theta_e, omega_e)
    np.testing.assert_allclose(u_d, trace["out.u_d_ref_V"], atol=1e-12)
    np.testing.assert_allclose(u_q, trace["out.u_q_ref_V"], atol=1e-12)
    fit = d_axis_fit(u_d, trace["motor.i_d"], trace["motor.i_q"], omega_e, path.T_i)
    plant = plant_values(config)
    assert fit.L_q == pytest.approx(plant["motor.L_q"], rel=0.005)
    assert fit.L_d == pytest.approx(plant["motor.L_d"], rel=0.001)
    assert fit.R_s == pytest.approx(plant["motor.R_s"], rel=0.05)


@pytest.mark.parametrize(
    "edits",
    [(), ((JERK_9_MS, JERK_50_MS),)],
    ids=["jerk filter 9 ms (default)", "jerk filter 50 ms"],
)
def test_the_rebuilt_stator_voltage_gives_the_motors_q_inductance(
    tmp_path: Path, program: Path, edits: tuple[tuple[str, str], ...]
) -> None:
    # the default drive: dead time and its compensation on, the delay's turn not advanced; the
    # references' own fit moves with the motion, the stator voltage's does not
    rebuilt, references, l_q = drive_fits(variant(tmp_path, "axis", *edits), program)
    # measured: 3.993 mH rebuilt, 4.357 mH from the references (T = 9 ms); 4.057 and 5.177 mH
    assert rebuilt == pytest.approx(l_q, rel=0.02)
    assert abs(references - rebuilt) > 0.05 * l_q


def test_the_references_read_the_controllers_decoupling_the_rebuilt_voltage_the_motor(
    tmp_path: Path, program: Path
) -> None:
    # the controller's decoupling gain 5 mH against the motor's 4 mH
    config = variant(tmp_path, "mismatch", (CONTROLLER_L_Q, "    L_q_H: 5.0e-3"))
    rebuilt, references, l_q = drive_fits(config, program)
    # measured 3.990 mH rebuilt, 4.443 mH from the references
    assert rebuilt == pytest.approx(l_q, rel=0.02)
    assert abs(references - rebuilt) > 0.05 * l_q


def quiet_path(**changes: float | bool) -> DriveVoltagePath:
    values: dict[str, float | bool] = {
        "T_i": 6.25e-5, "computation_delay": True, "angle_advance_periods": 0.0,
        "dead_time_comp_V": 0.0, "dead_time_comp_band_A": 0.5, "t_dead": 0.0, "f_pwm": 16e3,
        "u_f": 0.0, "i_reg": 0.5,
    }  # fmt: skip
    values.update(changes)
    return DriveVoltagePath(**values)  # pyright: ignore[reportArgumentType]


def stator(path: DriveVoltagePath, i_abc: tuple[float, float, float], omega_e: float):
    one = np.ones(1)
    return applied_stator_voltage(
        path, u_d_ref=2.0 * one, u_q_ref=40.0 * one, theta_e=0.3 * one, omega_e=omega_e * one,
        i_a=i_abc[0] * one, i_b=i_abc[1] * one, i_c=i_abc[2] * one, u_dc=560.0 * one,
    )  # fmt: skip


def test_the_computation_delay_turns_the_reference_by_its_angle() -> None:
    # 1.5 periods late without advance (0.5 without the delay), 1.5 - 0.5 with half a period's
    omega_e = 400.0
    for path, periods in [
        (quiet_path(), 1.5),
        (quiet_path(computation_delay=False), 0.5),
        (quiet_path(angle_advance_periods=0.5), 1.0),
    ]:
        turn = periods * omega_e * path.T_i
        u_d, u_q = stator(path, (0.0, 0.0, 0.0), omega_e)
        assert u_d[0] == pytest.approx(2.0 * np.cos(turn) + 40.0 * np.sin(turn), rel=1e-12)
        assert u_q[0] == pytest.approx(-2.0 * np.sin(turn) + 40.0 * np.cos(turn), rel=1e-12)


def test_a_compensation_equal_to_the_dead_time_cancels_at_rest() -> None:
    # currents beyond both bands, rotor at rest: the compensation is the inverter's loss
    drop = 560.0 * 1e-6 * 16e3 + 1.2
    path = quiet_path(dead_time_comp_V=drop, t_dead=1e-6, u_f=1.2)
    u_d, u_q = stator(path, (3.0, -1.0, -2.0), 0.0)
    assert (u_d[0], u_q[0]) == (pytest.approx(2.0, abs=1e-12), pytest.approx(40.0, abs=1e-12))
    # without the compensation the loss is the three square waves: |(4/3) drop| on the
    # current's 60-degree sector, against the current (a leads, b and c return)
    u_d, u_q = stator(quiet_path(t_dead=1e-6, u_f=1.2), (3.0, -1.0, -2.0), 0.0)
    loss_alpha = -(2.0 * drop + drop + drop) / 3.0
    np.testing.assert_allclose(
        (u_d[0], u_q[0]),
        (2.0 + np.cos(0.3) * loss_alpha, 40.0 - np.sin(0.3) * loss_alpha),
        rtol=1e-12,
    )


def test_bad_paths_and_fits_are_refused_by_name() -> None:
    with pytest.raises(
        ValueError, match=r"angle_advance_periods = 4\.0: must lie in \[0\.0, 3\.0\]"
    ):
        quiet_path(angle_advance_periods=4.0)
    with pytest.raises(ValueError, match=r"i_reg = 0\.0: must be > 0"):
        quiet_path(i_reg=0.0)
    with pytest.raises(ValueError, match=r"5, 5, 5, 4 samples of u_d, i_d, i_q, omega_e"):
        d_axis_fit(np.zeros(5), np.zeros(5), np.zeros(5), np.zeros(4), 1e-4)
