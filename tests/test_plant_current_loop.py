"""The drive's current loop behind a torque source (plant.current_loop via EffortSource) against
its closed forms, an energy balance, and the full electrical stage it stands for."""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import feed_twin
from feed_twin.core import signals as sig
from feed_twin.core.config import ConfigError
from feed_twin.plant.config import load_plant
from feed_twin.plant.current_loop import loop_poles
from feed_twin.plant.effort_source import CURRENT_LOOP_FIELDS
from feed_twin.sim.engine import Engine

ROOT = Path(feed_twin.__file__).resolve().parent.parent
# the truth machine's data sheet (config/truth_nominal.yaml, analysis.drive_stage)
R, L, KP, TI, K_T, RATIO, U_MAX = 0.6, 2.5e-3, 9.4, 4.2e-3, 0.45, 2.0 / 3.0, 173.2
LOOP = {"R_s": R, "L_s": L, "Kp_i": KP, "Ti_i": TI, "emf_ratio": RATIO, "u_max": U_MAX}


def _plant(J: float, *, unusual: bool = False, **loop: Any) -> Any:
    """A rotor driven by the loop; energy tracked in every test (one kernel to compile)."""
    params = {"domain": "rotational", "gain": K_T, "T_lag": 0.0, "f_max": 1e4} | LOOP | loop
    return load_plant(
        {
            "components": [
                {"name": "rotor", "type": "Inertia", "params": {"J": J}},
                {"name": "drive", "type": "EffortSource", "params": params},
            ],
            "connect": [["drive.flange", "rotor.flange"]],
        }
        | ({"unusual": ["rotor.J"]} if unusual else {}),
        source="loop",
    ).with_energy_tracking()


def _drive(n: int, i_ref: float) -> np.ndarray:
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_EFFORT_CMD] = i_ref
    drive[:, sig.OUT_ENABLED] = 1.0
    return drive


def _step(t: np.ndarray, i_ref: float) -> np.ndarray:
    """i(t) after a setpoint step at rest with the rotor held: the inverse Laplace transform
    of i_ref Kp (s + 1/Ti) / (L s (s - s1) (s - s2)) by partial fractions."""
    s1, s2 = (p.real for p in loop_poles(R, L, KP, TI))
    out = np.full_like(t, 1.0)
    for s, other in ((s1, s2), (s2, s1)):
        out += KP * (s + 1.0 / TI) / (L * s * (s - other)) * np.exp(s * t)
    return i_ref * out


def test_the_step_answer_is_the_closed_form_of_the_pi_on_the_windings() -> None:
    """Rotor held (an inertia of 1e9 kg m^2: no back-EMF), setpoint step of 5 A: the loop's
    two real poles (-238 and -3762 1/s on the data sheet), exact to RK4's error at a 10 us
    step; at the truth twin's 250 us tick (h |s| = 0.94 on the fast pole) within 1 % of the
    step, and the ramp-free steady state exact."""
    fast = [abs(p) for p in loop_poles(R, L, KP, TI)]
    assert min(fast) == pytest.approx(238.0, rel=2e-3)
    assert max(fast) == pytest.approx(3762.0, rel=2e-3)
    for h, tol in ((1e-5, 1e-6), (2.5e-4, 1e-2)):
        n = round(0.03 / h)
        res = Engine(_plant(1e9, unusual=True), base_period_s=h).run(n, drive=_drive(n, 5.0))
        np.testing.assert_allclose(res["drive.i"], _step(res.t, 5.0), atol=tol * 5.0)
        # the first tick from rest: i rises as Kp i_ref t / L to first order
        assert res["drive.i"][0] == 0.0
    assert res["drive.effort"][-1] == pytest.approx(K_T * 5.0, rel=1e-3)


def test_the_current_lags_by_ti_over_kp_times_the_back_emf_rate() -> None:
    """A free rotor under a constant setpoint: the back-EMF ramps with the speed, the
    integrator must ramp the voltage with it, and the current settles below the setpoint by
    (Ti/Kp) k_e domega/dt, with domega/dt = K_t i / J:
        i = i_ref / (1 + Ti k_e K_t / (Kp J)),
    the lag that follows the acceleration and that an ideal source cannot show."""
    J, i_ref, h = 1.38e-3, 10.0, 1e-5
    n = round(0.06 / h)  # 14 times the loop's slow time constant
    res = Engine(_plant(J), base_period_s=h).run(n, drive=_drive(n, i_ref))
    lag = TI * RATIO * K_T * K_T / (KP * J)  # 2.1 %
    assert res["drive.i"][-1] == pytest.approx(i_ref / (1.0 + lag), rel=1e-6)
    alpha = np.gradient(res["rotor.omega"], h)[-10]
    assert alpha == pytest.approx(K_T * res["drive.i"][-1] / J, rel=1e-4)


def test_the_windings_balance_their_energy() -> None:
    """Supply u i / emf_ratio = copper loss + magnetic and kinetic energy, over a start."""
    plant = _plant(1.38e-3)
    n = 2000
    engine = Engine(plant, base_period_s=1e-5)
    res = engine.run(n, drive=_drive(n, 10.0))
    x = engine.x
    energy = {s: x[plant.state_index[s]] for s in plant.state_names if s.startswith("energy.")}
    source = sum(e for s, e in energy.items() if plant.energy_kinds[s] == "source")
    losses = sum(e for s, e in energy.items() if plant.energy_kinds[s] == "loss")
    i, omega = x[plant.state_index["drive.i"]], x[plant.state_index["rotor.omega"]]
    stored = 0.5 * L * i * i / RATIO + 0.5 * 1.38e-3 * omega * omega
    assert losses > 0.1 * source > 0.0
    assert source == pytest.approx(stored + losses, rel=1e-6)
    assert res["drive.u"][0] == pytest.approx(KP * 10.0, rel=1e-12)  # first sample: Kp e


def test_a_disabled_drive_leaves_the_windings_off() -> None:
    n = 100
    drive = _drive(n, 5.0)
    drive[:, sig.OUT_ENABLED] = 0.0
    res = Engine(_plant(1e-3), base_period_s=1e-4).run(n, drive=drive)
    assert np.all(res["drive.i"] == 0.0)
    assert np.all(res["drive.z"] == 0.0)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"Ti_i": None}, "Ti_i = None: the current loop needs all of R_s, L_s"),
        ({"L_s": 0.0}, "L_s = 0.0: must be > 0"),
        ({"T_lag": 1e-3}, "T_lag = 0.001: must be 0 with a current loop (its own lag)"),
        ({"domain": "translational"}, "domain = 'translational': a current loop drives a motor"),
        ({"gain": 0.0}, "gain = 0.0: a current loop's torque constant must not be 0"),
    ],
)
def test_bad_current_loops_are_named(change: dict[str, Any], message: str) -> None:
    params = {"domain": "rotational", "gain": K_T, "T_lag": 0.0, "f_max": 1e4} | LOOP | change
    params = {k: v for k, v in params.items() if v is not None}
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_plant(
            {
                "components": [
                    {"name": "rotor", "type": "Inertia", "params": {"J": 1e-3}},
                    {"name": "drive", "type": "EffortSource", "params": params},
                ],
                "connect": [["drive.flange", "rotor.flange"]],
            },
            source="bad",
        )


@pytest.mark.slow
def test_the_loop_stands_for_the_full_electrical_stage() -> None:
    """The truth twin on a planned move of the truth machine's program, three ways: its ideal
    torque source, the current loop, and analysis.drive_stage's full stage at zero dead time
    (Pmsm, averaged inverter, current sensor and the controller's sampled 8 kHz current loop
    acting one period late: 4-5x the cost). The loop's position stays within 0.1 um RMS of the
    full stage's (measured 0.04 um on the whole record), the ideal source's does not (0.6 um);
    the loop's continuous PI is the sampled one's low-frequency model, and the efforts agree
    within 0.5 % of their RMS."""
    from feed_twin.analysis.drive_stage import expand
    from feed_twin.analysis.model_doc import ModelDoc
    from feed_twin.analysis.twin import Drive, Twin
    from feed_twin.truth import command

    doc = ModelDoc.load(ROOT / "config/truth_nominal.yaml")
    ideal_data = copy.deepcopy(doc.data)
    for entry in ideal_data["plant"]["components"]:
        if entry["type"] == "EffortSource":
            for name in CURRENT_LOOP_FIELDS:
                del entry["params"][name]
    ideal = ModelDoc(
        data=ideal_data,
        source="ideal",
        ties=doc.ties,
        asymmetric=doc.asymmetric,
        reference_gain=doc.reference_gain,
    )
    t_nc, x_nc = command()
    keep = t_nc <= 2.5  # the program's first moves
    t, x = t_nc[keep], x_nc[keep]
    v = np.gradient(x, t)
    drive = Drive(
        t_s=t,
        pos_ref_m=x,
        vel_ref_m_s=v,
        acc_ref_m_s2=np.gradient(v, t),
        effort_add=None,
        force_ext_N=None,
        x0_m=float(x[0]),
        sensor="motor_encoder",
    )
    out = {}
    for name, model in (("ideal", ideal), ("loop", doc), ("stage", expand(doc))):
        twin = Twin.compile(model)
        out[name] = twin.simulate(drive, twin.nominal[None, :])
    dx = {k: float(np.sqrt(np.mean((out[k].x_m[0] - out["stage"].x_m[0]) ** 2))) for k in out}
    assert dx["loop"] < 1e-7
    assert dx["ideal"] > 5.0 * dx["loop"]
    effort = out["stage"].effort[0]
    de = out["loop"].effort[0] - effort
    assert math.sqrt(np.mean(de**2)) < 5e-3 * math.sqrt(np.mean(effort**2))


def test_the_truth_twins_loop_is_its_drive_stages_data_sheet() -> None:
    """config/truth_nominal.yaml gives the drive's data sheet twice: the loop on its source
    and analysis.drive_stage (the full stage for the dead time); they must agree."""
    from feed_twin.analysis.drive_stage import drive_stage
    from feed_twin.analysis.model_doc import ModelDoc

    doc = ModelDoc.load(ROOT / "config/truth_nominal.yaml")
    stage = drive_stage(doc)
    assert stage is not None
    (source,) = doc.of_type("EffortSource")
    params = doc.component(source)["params"]
    assert (params["R_s"], params["L_s"]) == (stage.R_s_ohm, stage.L_H)
    assert (params["Kp_i"], params["Ti_i"]) == (stage.Kp_V_A, stage.Ti_s)
    assert params["emf_ratio"] == pytest.approx(2.0 / 3.0, rel=1e-15)  # PMSM, d/q
    assert params["u_max"] == pytest.approx(stage.u_dc_V / math.sqrt(3.0), rel=1e-15)
    assert not stage.back_emf_ff


def test_a_loop_too_fast_for_the_step_is_refused() -> None:
    """L = 2.5e-5 H puts the fast pole near 3.8e5 1/s: at 250 us that is h |s| = 94, RK4
    diverges; check_step and the batch's check_steps both say so, and 64 sub-steps pass."""
    from feed_twin.sim.batch import check_steps
    from feed_twin.sim.engine import check_step

    plant = _plant(1e-3, L_s=2.5e-5)
    p = plant.nominal_params()
    plant.fill_derived(p)
    message = "plant.drive: step 0.00025 s times its states' fastest rate"
    with pytest.raises(ValueError, match=re.escape(message)):
        check_step(plant, p, 2.5e-4, 1)
    assert message in check_steps(plant, p[None, :], 2.5e-4, 1)[0]
    check_step(plant, p, 2.5e-4, 64)
    assert check_steps(plant, np.vstack([p, p]), 2.5e-4, 64) == ["", ""]
