"""Mechanical physics of the assembled plant: rigid bodies, modes, backlash, friction, energy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from feed_twin.core import signals as sig
from feed_twin.plant.axial_compliance import AxialCompliance
from feed_twin.plant.backlash import backlash_force
from feed_twin.plant.config import load_plant
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.engine import Engine


def _effort_drive(n: int, effort: np.ndarray | float) -> np.ndarray:
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_EFFORT_CMD] = effort
    drive[:, sig.OUT_ENABLED] = 1.0
    return drive


def _source(gain: float = 1.0) -> dict:
    return {
        "name": "drive",
        "type": "EffortSource",
        "params": {"domain": "translational", "gain": gain, "T_lag": 0.0, "f_max": 1e6},
    }


def _table_on(friction: dict):
    """A 20 kg table on the guide-friction component `friction` (named friction), driven by a
    force source."""
    return load_plant(
        {
            "components": [
                {"name": "table", "type": "Mass", "params": {"m": 20.0}},
                friction,
                _source(),
            ],
            "connect": [["table.flange", "friction.flange"], ["table.flange", "drive.flange"]],
        },
        source="friction",
    )


def _viscous(name: str, F_v: float, F_c: float = 0.0, dF_s: float = 0.0) -> dict:
    return {
        "name": name,
        "type": "GuideFriction",
        "params": {
            "F_c_pos": F_c,
            "F_c_neg": F_c,
            "F_v_pos": F_v,
            "F_v_neg": F_v,
            "dF_s": dF_s,
            "v_s": 0.01,
            "v_reg": 1e-4,
        },
    }


def test_rigid_body_through_the_screw_accelerates_as_force_over_reflected_mass():
    m, J, lead, force = 10.0, 2e-4, 0.005, 10.0
    plant = load_plant(
        {
            "components": [
                {"name": "table", "type": "Mass", "params": {"m": m}},
                {"name": "rotor", "type": "Inertia", "params": {"J": J}},
                {"name": "screw", "type": "BallScrew", "params": {"lead": lead, "efficiency": 1}},
                _source(),
            ],
            "connect": [
                ["rotor.flange", "screw.rot"],
                ["screw.trans", "table.flange"],
                ["drive.flange", "table.flange"],
            ],
        },
        source="rigid",
    )
    assert [c.name for c in plant.coordinates] == ["table"]
    engine = Engine(plant, base_period_s=1e-3)
    n = 1000
    res = engine.run(n + 1, drive=_effort_drive(n + 1, force))
    M = m + J * (2.0 * math.pi / lead) ** 2  # the rotor reflected through the screw
    t = res.t
    np.testing.assert_allclose(res["table.s"], 0.5 * force / M * t**2, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res["table.v"], force / M * t, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res["table.a"], force / M, rtol=1e-12)


def _conservative_axis():
    """The default axis with every damper, friction and loss off, backlash closed."""
    axis = load_axis_config("config/axis_default.yaml")
    return axis.plant.with_params(
        coupling={"d": 0.0},
        screw_shaft={"d": 0.0},
        axial={"d": 0.0},
        backlash={"d": 0.0, "gap": 0.0},
        guides={"F_c_pos": 0.0, "F_c_neg": 0.0, "F_v_pos": 0.0, "F_v_neg": 0.0, "dF_s": 0.0},
        motor={"T_c": 0.0, "b": 0.0},
        screw={"efficiency": 1.0},
    )


MECH = ("motor", "hub_screw", "screw_shaft", "nut", "table")


def _independent_frequencies(plant, s_table: float) -> np.ndarray:
    """Undamped natural frequencies [rad/s] from hand-built stiffness and inertia matrices."""
    c = plant.components
    r = c["screw"].lead / (2.0 * math.pi)
    J_shaft = c["screw_shaft"].slots()["J"]
    M = np.diag(
        [
            c["motor"].J + c["hub_motor"].J,
            c["hub_screw"].J + 0.5 * J_shaft,
            0.5 * J_shaft,
            c["nut"].m,
            c["table"].m,
        ]
    )
    k_c = c["coupling"].k
    k_t = c["screw_shaft"].slots()["k_t"]
    k_a = c["axial"].stiffness(s_table)
    k_b = c["backlash"].k
    # potential: k_c(q0-q1)^2/2 + k_t(q1-q2)^2/2 + k_a(r q2 - q3)^2/2 + k_b(q3 - q4)^2/2
    K = np.zeros((5, 5))
    for (i, j), k, (a, b) in (
        ((0, 1), k_c, (1.0, 1.0)),
        ((1, 2), k_t, (1.0, 1.0)),
        ((2, 3), k_a, (r, 1.0)),
        ((3, 4), k_b, (1.0, 1.0)),
    ):
        g = np.zeros(5)
        g[i], g[j] = a, -b
        K += k * np.outer(g, g)
    w2 = scipy.linalg.eigh(K, M, eigvals_only=True)
    return np.sqrt(np.clip(np.sort(w2)[1:], 0.0, None))  # drop the rigid-body mode


def _linearised_frequencies(plant, s_table: float) -> np.ndarray:
    x = plant.initial_state({"table": s_table})
    names = [n for c in plant.coordinates for n in (c.position_state, c.velocity_state)]
    A = plant.linearize(x, plant.nominal_params(), states=names)
    lam = np.linalg.eigvals(A)
    w = np.sort(np.abs(lam.imag[lam.imag > 1e-3]))
    return w


@pytest.mark.parametrize("s_table", [-0.3, 0.0, 0.3])
def test_linearised_chain_has_the_eigenfrequencies_of_its_stiffness_and_inertia(s_table):
    plant = _conservative_axis()
    expected = _independent_frequencies(plant, s_table)
    got = _linearised_frequencies(plant, s_table)
    assert len(got) == 4
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_first_axial_mode_drops_as_the_table_moves_away_from_the_fixed_bearing():
    plant = _conservative_axis()
    positions = [0.0, 0.2, 0.4, 0.6, 0.8]  # machine X: nut 0.1 m .. 0.9 m from the bearing
    first = [_linearised_frequencies(plant, s)[0] for s in positions]
    assert all(np.diff(first) < 0.0)
    # fixed-free: k_screw = E*A/x softens 9x from x = 0.1 m to 0.9 m; in series with bearing
    # and nut the axial stiffness drops 2.5x, and the mode (axial spring against table plus
    # the reflected rotor) by a good part of sqrt(2.5)
    axial = plant.components["axial"]
    assert isinstance(axial, AxialCompliance), f"'axial' is a {type(axial).__name__}"
    k_ratio = axial.stiffness(positions[-1]) / axial.stiffness(positions[0])
    assert k_ratio == pytest.approx(0.405, abs=0.01)
    assert math.sqrt(k_ratio) < first[-1] / first[0] < 0.8
    np.testing.assert_allclose(
        first, [_independent_frequencies(plant, s)[0] for s in positions], rtol=1e-5
    )


def test_backlash_passes_no_force_inside_the_gap_and_a_spring_force_outside():
    gap, k, d = 1e-4, 1e7, 50.0
    for delta in np.linspace(-0.5 * gap, 0.5 * gap, 11):
        assert backlash_force.py_func(delta, 0.3, gap, k, d) == (0.0, 0.0, 0.0)
    f, e, _ = backlash_force.py_func(0.5 * gap + 1e-6, 0.0, gap, k, d)
    assert f == pytest.approx(k * 1e-6, rel=1e-9)
    assert e == pytest.approx(0.5 * k * 1e-12, rel=1e-9)
    f, _, _ = backlash_force.py_func(-0.5 * gap - 2e-6, 0.0, gap, k, d)
    assert f == pytest.approx(-2e-6 * k, rel=1e-9)
    # separating faces: the damper may not pull them together
    f, _, _ = backlash_force.py_func(0.5 * gap + 1e-9, -1.0, gap, k, d)
    assert f == 0.0


def test_backlash_lost_motion_at_reversal_equals_the_gap():
    gap, k, F_vb = 50e-6, 1e7, 200.0
    plant = load_plant(
        {
            "components": [
                {"name": "nut", "type": "Mass", "params": {"m": 1.0}},
                {"name": "table", "type": "Mass", "params": {"m": 1.0}},
                {"name": "backlash", "type": "Backlash", "params": {"gap": gap, "k": k, "d": 0}},
                _viscous("nut_friction", 200.0),
                _viscous("table_friction", F_vb),
                _source(),
            ],
            "connect": [
                ["nut.flange", "backlash.a"],
                ["backlash.b", "table.flange"],
                ["nut.flange", "nut_friction.flange"],
                ["table.flange", "table_friction.flange"],
                ["drive.flange", "nut.flange"],
            ],
        },
        source="backlash",
    )
    engine = Engine(
        plant,
        base_period_s=1e-4,
        record=["nut.s", "table.s", "table.v", "backlash.force"],
    )
    n = 1000  # 0.1 s each way; the time constant (2 kg / 400 N s/m) is 5 ms
    effort = np.concatenate([np.full(n, 40.0), np.full(n, -40.0)])
    res = engine.run(2 * n, drive=_effort_drive(2 * n, effort))
    delta = res["nut.s"] - res["table.s"]
    f_contact = F_vb * abs(res["table.v"][n - 1])
    lost = delta[n - 1] - delta[-1] - 2.0 * f_contact / k
    assert lost == pytest.approx(gap, rel=1e-3)
    inside = np.abs(delta) < 0.5 * gap
    assert inside.sum() > 5  # the reversal crosses the gap over several samples
    assert np.all(res["backlash.force"][inside] == 0.0)


def test_friction_balances_the_drive_force_at_the_formula_velocity():
    """Steady sliding at constant force: the drive force equals F(v) of Coulomb+Stribeck+viscous."""
    F_c_pos, F_c_neg, F_v_pos, F_v_neg, dF_s, v_s = 20.0, 30.0, 200.0, 300.0, 8.0, 0.02
    v_reg = 1e-4
    comp = {
        "name": "friction",
        "type": "GuideFriction",
        "params": {
            "F_c_pos": F_c_pos,
            "F_c_neg": F_c_neg,
            "F_v_pos": F_v_pos,
            "F_v_neg": F_v_neg,
            "dF_s": dF_s,
            "v_s": v_s,
            "v_reg": v_reg,
        },
    }
    plant = _table_on(comp)
    forces = np.array([-80.0, -55.0, -42.0, 32.0, 40.0, 80.0])  # beyond breakaway
    engine = Engine(plant, base_period_s=1e-4, substeps=4, record=["table.v", "friction.force"])
    n = 20000  # 2 s, time constant m/F_v <= 0.1 s
    for f in forces:
        res = engine.run(n, drive=_effort_drive(n, f))
        v = res["table.v"][-1]
        # independent formula, far outside the regularisation band (|v| >> v_reg)
        if v > 0:
            expected = F_c_pos + dF_s * math.exp(-((v / v_s) ** 2)) + F_v_pos * v
        else:
            expected = -(F_c_neg + dF_s * math.exp(-((v / v_s) ** 2))) + F_v_neg * v
        # beyond 15/8 v_reg the smooth sign is exactly +/-1: no regularisation error is left
        assert abs(v) > 10 * v_reg
        assert expected == pytest.approx(f, rel=1e-6)
        assert res["friction.force"][-1] == pytest.approx(f, rel=1e-6)


def _mechanical_chain(plant):
    """The drive train of `plant` without the electrical side: the rotor becomes an Inertia."""
    from feed_twin.plant.assembly import PlantModel
    from feed_twin.plant.inertia import Inertia

    electrical = {"bus", "inverter", "current_sensor", "encoder"}
    comps = [
        (n, Inertia(J=c.J) if n == "motor" else c)
        for n, c in plant.components.items()
        if n not in electrical
    ]
    keep = {n for n, _ in comps}
    conns = [
        (a, b) for a, b in plant.connections if a.split(".")[0] in keep and b.split(".")[0] in keep
    ]
    return PlantModel(comps, conns, source="chain")


def test_lead_error_shifts_the_relaxed_nut_by_the_sinusoid():
    lead, amplitude, phase = 0.01, 4e-6, 0.7
    plant = _mechanical_chain(_conservative_axis()).with_params(
        axial={
            "lead_error_amplitude": amplitude,
            "lead_error_period": lead,
            "lead_error_phase": phase,
        }
    )
    outputs = plant.namespace()["outputs"]
    aux = np.zeros(len(plant.aux_names))
    p = plant.nominal_params()
    for phi in (0.3, 1.9, 4.4):
        x = plant.initial_state()
        x[plant.state_index["screw_shaft.phi"]] = phi
        s_ideal = lead / (2.0 * math.pi) * phi
        error = amplitude * math.sin(2.0 * math.pi * s_ideal / lead + phase)
        x[plant.state_index["nut.s"]] = s_ideal + error
        outputs(0.0, x, p, np.zeros(sig.OUT_SIZE), np.zeros(1), np.zeros(3), aux)
        assert aux[plant.aux_names.index("axial.lead_error")] == pytest.approx(error, rel=1e-12)
        assert aux[plant.aux_names.index("axial.force")] == pytest.approx(0.0, abs=1e-6)


def test_mechanical_energy_is_conserved_with_damping_and_friction_off():
    # with a lead error too: the screw side receives -f*(1 + e'), the virtual work of e
    plant = _mechanical_chain(_conservative_axis()).with_params(
        axial={"lead_error_amplitude": 5e-6, "lead_error_period": 0.01, "lead_error_phase": 0.0}
    )
    # RK4 is not symplectic: it dissipates a mode at about (h*omega)^6/144 per step. The nut on
    # its springs (18.7e3 rad/s) needs 8 sub-steps for a drift below 1e-5 over 0.1 s; with one
    # sub-step the same mode is damped by about 1 % numerically (physically 13 %).
    engine = Engine(plant, base_period_s=6.25e-5, substeps=8, record=list(plant.stored_names))
    x0 = plant.initial_state({"table": 0.1})
    x0[plant.state_index["motor.phi"]] += 2e-3  # twist the coupling and the screw
    x0[plant.state_index["table.v"]] = 0.05
    engine.reset(x0=x0)
    res = engine.advance(1600)
    stored = np.sum([res[n] for n in plant.stored_names], axis=0)
    assert stored[0] == pytest.approx(0.25 + 0.5 * 3.0e4 * 2e-3**2, rel=0.05)
    np.testing.assert_allclose(stored, stored[0], rtol=2e-5)


def test_a_drifting_friction_grows_by_its_rate_per_second():
    """GuideFriction with drift_per_s: the law times (1 + rate * t), t the run's time (its age
    state). Viscous only, a constant force: the force it reports is F_v (1 + r t) v at every
    sample, and the table slows to f / (F_v (1 + r T)) (quasi-steady: m / F_v = 0.07 s is
    short against the drift). Without a drift the component has no age state and no drift
    slot (the code a model without drift runs is the code it always ran)."""
    F_v, rate, force, h = 300.0, 0.05, 30.0, 1e-4
    comp = _viscous("friction", F_v)
    comp["params"]["drift_per_s"] = rate
    plant = _table_on(comp)
    n = 20000  # 2 s
    engine = Engine(plant, base_period_s=h, substeps=4, record=["table.v", "friction.force"])
    res = engine.run(n, drive=_effort_drive(n, force))
    t = h * np.arange(n)  # the force at each period's start (the age then)
    v, f = res["table.v"], res["friction.force"]
    assert f == pytest.approx(F_v * (1.0 + rate * t) * v, rel=1e-9, abs=1e-12)
    assert v[-1] == pytest.approx(force / (F_v * (1.0 + rate * t[-1])), rel=1e-2)
    from feed_twin.plant.guide_friction import GuideFriction

    still = GuideFriction(**_viscous("friction", F_v)["params"])
    assert still.states() == () and "drift_per_s" not in still.slots()


def test_a_drift_rate_out_of_range_is_refused():
    from feed_twin.plant.guide_friction import GuideFriction

    params = dict(_viscous("friction", 300.0)["params"], drift_per_s=2.0)
    with pytest.raises(ValueError, match=r"drift_per_s = 2.0: must lie in \[-1.0, 1.0\]"):
        GuideFriction(**params)
