"""Electrical physics: PMSM torque, inverter models, the energy balance of a closed-loop move."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.core import signals as sig
from feed_twin.plant.config import load_plant
from feed_twin.plant.pmsm import CoggingHarmonic
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.engine import Engine

U_DC = 560.0
F_PWM = 16000.0


def _drive_plant(
    *, L_d: float, L_q: float, model: str = "averaged", t_dead: float = 0.0, u_f: float = 0.0
):
    return load_plant(
        {
            "components": [
                {"name": "bus", "type": "DcBus", "params": {"u_0": U_DC, "R_i": 0.0}},
                {
                    "name": "inverter",
                    "type": "Inverter",
                    "params": {
                        "model": model,
                        "f_pwm": F_PWM,
                        "t_dead": t_dead,
                        "u_f": u_f,
                        "i_reg": 0.5,
                    },
                },
                {
                    "name": "motor",
                    "type": "Pmsm",
                    "params": {
                        "R_s": 0.35,
                        "L_d": L_d,
                        "L_q": L_q,
                        "psi_pm": 0.3167,
                        "p": 4,
                        "R_fe": None,
                        "J": 3.1e-3,
                        "T_c": 0.0,
                        "b": 0.0,
                        "omega_reg": 0.01,
                        "i_max": 1000.0,
                        "T_open": 2.0e-4,
                    },
                },
                {"name": "load", "type": "Inertia", "params": {"J": 1.0e3}},
            ],
            # a flywheel that holds the speed while the torque is measured: no feed axis has it
            "unusual": ["load.J"],
            "connect": [
                ["bus.dc", "inverter.dc"],
                ["inverter.ac", "motor.ac"],
                ["motor.flange", "load.flange"],
            ],
        },
        source="drive",
    )


def _duties(n: int, u_alpha: float, u_beta: float) -> np.ndarray:
    u_a = u_alpha
    u_b = -0.5 * u_alpha + 0.5 * math.sqrt(3.0) * u_beta
    u_c = -0.5 * u_alpha - 0.5 * math.sqrt(3.0) * u_beta
    drive = np.zeros((n, sig.OUT_SIZE))
    for slot, u in zip(
        (sig.OUT_DUTY_A, sig.OUT_DUTY_B, sig.OUT_DUTY_C), (u_a, u_b, u_c), strict=True
    ):
        drive[:, slot] = 0.5 + u / U_DC
    drive[:, sig.OUT_ENABLED] = 1.0
    return drive


@pytest.mark.parametrize(
    ("L_d", "L_q", "u_d", "u_q"),
    [(4e-3, 4e-3, 0.0, 1.75), (3e-3, 6e-3, -0.7, 1.75)],
)
def test_steady_state_torque_accelerates_the_rotor_as_the_dq_formula_says(L_d, L_q, u_d, u_q):
    """At standstill (rotor at angle 0: d along phase a) a constant (u_d, u_q) settles at
    i = u/R_s; the torque 1.5*p*(psi*i_q + (L_d - L_q)*i_d*i_q) then accelerates the inertia."""
    plant = _drive_plant(L_d=L_d, L_q=L_q)
    h = 1.0 / F_PWM
    n = 4000  # 0.25 s: 20 electrical time constants
    engine = Engine(plant, base_period_s=h)
    res = engine.run(n, drive=_duties(n, u_d, u_q))
    R_s, p, psi = 0.35, 4, 0.3167
    i_d, i_q = u_d / R_s, u_q / R_s
    # the rotor creeps (omega < 1e-2 rad/s, angle < 1e-3 rad electrical), so the back-EMF and
    # the turning of the stator voltage in the rotor frame shift the currents by < 2e-3 * |i|
    i_scale = math.hypot(i_d, i_q)
    assert res["motor.i_q"][-1] == pytest.approx(i_q, abs=2e-3 * i_scale)
    assert res["motor.i_d"][-1] == pytest.approx(i_d, abs=2e-3 * i_scale)
    i_d_sim, i_q_sim = res["motor.i_d"][-1], res["motor.i_q"][-1]
    omega = res["motor.omega"]
    torque = 1.5 * p * (psi * i_q_sim + (L_d - L_q) * i_d_sim * i_q_sim)
    assert res["motor.tau_e"][-1] == pytest.approx(torque, rel=1e-12)
    # the terminal power is copper loss + mechanical power + the change of magnetic energy, and
    # the last is of order 1e-4 here (the stator voltage turns slowly in the rotor frame)
    copper = 1.5 * R_s * (i_d_sim**2 + i_q_sim**2)
    p_mech = res["motor.p_mech"][-1]
    assert p_mech == pytest.approx(torque * omega[-1], rel=1e-12)
    assert res["motor.p_elec"][-1] == pytest.approx(copper + p_mech, rel=2e-4)
    J = 3.1e-3 + 1.0e3
    accel = (omega[-1] - omega[-401]) / (400 * h)
    assert accel == pytest.approx(torque / J, rel=2e-3)


def test_switching_and_averaged_inverters_agree_in_mean_currents():
    """Centre-aligned PWM sampled at the period start sees the mean of the ripple: the switching
    model's samples equal the averaged model's currents, dead time and drops included."""
    h = 1.0 / F_PWM
    n = 3200  # 0.2 s
    drive = _duties(n, 30.0, -2.0)
    results = {}
    for model in ("averaged", "switching"):
        plant = _drive_plant(L_d=4e-3, L_q=4e-3, model=model, t_dead=1.0e-6, u_f=1.2)
        engine = Engine(plant, base_period_s=h, record=["motor.i_a", "motor.i_b", "motor.i_c"])
        res = engine.run(n, drive=drive)
        results[model] = np.array([res[f"motor.i_{x}"][-1] for x in "abc"])
    avg, sw = results["averaged"], results["switching"]
    assert np.min(np.abs(avg)) > 5 * 0.5  # every phase current well outside the sign band
    np.testing.assert_allclose(sw, avg, atol=0.01 * np.max(np.abs(avg)))
    # dead time lowers the voltage the current flows against: without it the currents differ
    plain = Engine(_drive_plant(L_d=4e-3, L_q=4e-3), base_period_s=h, record=["motor.i_a"])
    i_plain = plain.run(n, drive=drive)["motor.i_a"][-1]
    assert abs(i_plain - avg[0]) > 5.0


@pytest.mark.slow
def test_energy_balance_of_a_closed_loop_move_closes():
    """Supply + cutting work = change of stored energy + all losses, over a move with a load."""
    axis = load_axis_config("config/axis_default.yaml")
    plant = axis.plant.with_energy_tracking()
    axis = type(axis)(**{**axis.__dict__, "plant": plant})
    engine = build_engine(axis)
    h = engine.h
    n = round(0.4 / h)
    t = np.arange(n) * h
    v = np.clip(np.minimum(t / 0.05, (0.35 - t) / 0.05), 0.0, 1.0) * 0.1  # trapezoid, 0.1 m/s
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_VEL_M_S] = v
    ref[:, sig.REF_POS_M] = np.cumsum(v) * h
    ref[:, sig.REF_ACC_M_S2] = np.gradient(v, h)
    ext = np.full((n, 1), -300.0)  # a cutting force against the feed
    res = engine.run(n, ref=ref, ext=ext)
    assert res["table.s"][-1] == pytest.approx(ref[-1, sig.REF_POS_M], abs=1e-4)
    x_end = engine.x
    energy = {
        name: x_end[plant.state_index[name]]
        for name in plant.state_names
        if name.startswith("energy.")
    }
    source = sum(e for n_, e in energy.items() if plant.energy_kinds[n_] == "source")
    losses = sum(e for n_, e in energy.items() if plant.energy_kinds[n_] == "loss")
    stored = np.sum([res[n_] for n_ in plant.stored_names], axis=0)
    # the energy states are integrals up to the end of the run: evaluate the stored energy there
    ns = plant.namespace()
    aux = np.zeros(len(plant.aux_names))
    ns["outputs"](0.0, x_end, engine.p, engine.out, np.zeros(1), np.zeros(3), aux)
    stored_end = sum(aux[plant.aux_names.index(n_)] for n_ in plant.stored_names)
    delta_stored = stored_end - stored[0]
    assert losses > 10.0  # joules: a real move
    assert all(energy[n_] >= -1e-9 for n_ in energy if plant.energy_kinds[n_] == "loss")
    residual = source - delta_stored - losses
    assert residual == pytest.approx(0.0, abs=5e-3 * source)


def test_currents_die_out_when_the_inverter_is_switched_off():
    plant = _drive_plant(L_d=4e-3, L_q=4e-3)
    h = 1.0 / F_PWM
    on, off = 1600, 160  # 0.1 s on, then 10 ms off (50 decay times of 0.2 ms)
    drive = _duties(on + off, 3.0, 0.0)
    drive[on:, sig.OUT_ENABLED] = 0.0
    res = Engine(plant, base_period_s=h).run(on + off, drive=drive)
    i_on = math.hypot(res["motor.i_d"][on - 1], res["motor.i_q"][on - 1])
    assert i_on > 5.0
    after = np.hypot(res["motor.i_d"][on + 16 :], res["motor.i_q"][on + 16 :])
    assert np.max(after) < math.exp(-4.0) * i_on  # 1 ms = 5 decay times later


def test_cogging_torque_makes_the_rotor_swing_at_its_detent_frequency():
    """Near a detent, tau = A*sin(n*phi + pi) ~ -A*n*phi: omega = sqrt(A*n/J) with no current."""
    order, amplitude, J = 36, 0.08, 3.1e-3 + 1.0e3
    plant = _drive_plant(L_d=4e-3, L_q=4e-3).with_params(
        motor={"cogging": (CoggingHarmonic(order=order, amplitude=amplitude, phase=math.pi),)}
    )
    names = ["motor.phi", "motor.omega"]
    A = plant.linearize(plant.initial_state(), plant.nominal_params(), states=names)
    omega = np.abs(np.linalg.eigvals(A).imag).max()
    assert omega == pytest.approx(math.sqrt(amplitude * order / J), rel=1e-6)


def test_switching_inverter_needs_one_pwm_period_per_tick():
    plant = _drive_plant(L_d=4e-3, L_q=4e-3, model="switching")
    with pytest.raises(
        ValueError,
        match=r"^drive: plant.inverter.f_pwm = 16000.0: the switching inverter needs one PWM "
        r"period per base tick, 1/base_period_s = 8000.0 Hz$",
    ):
        Engine(plant, base_period_s=1.25e-4)
