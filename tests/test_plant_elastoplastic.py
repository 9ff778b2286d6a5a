"""ElastoPlasticFriction: the contact that stays deflected the way it slid, against closed forms
and against the Karnopp contact (StictionFriction) that lets go while sliding."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.core import signals as sig
from feed_twin.plant.config import load_plant
from feed_twin.plant.elastoplastic_friction import ElastoPlasticFriction, elastoplastic_force
from feed_twin.plant.stiction_friction import stiction_force
from feed_twin.sim.engine import Engine

LAW = elastoplastic_force.py_func
F_HOLD, K_S, D_S, R_SLIP = 20.0, 1e7, 3e4, 1e3
Z_MAX = F_HOLD / K_S


def _law(z: float, v: float, d_s: float = D_S):
    return LAW(z, v, F_HOLD, K_S, d_s, R_SLIP)


def test_below_the_holding_force_it_is_a_damped_presliding_spring():
    z, v = -0.6 * Z_MAX, 2e-5
    f, rate, stored, loss = _law(z, v)
    assert f == pytest.approx(K_S * z + D_S * v, rel=1e-12)
    assert rate == v
    assert stored == pytest.approx(0.5 * K_S * z * z, rel=1e-12)
    assert loss == pytest.approx(D_S * v * v, rel=1e-12)  # the spring's power is stored


def test_sliding_it_carries_the_holding_force_at_any_speed_and_dissipates_it():
    for v in (1e-6, 1e-3, 0.1):
        for sign in (1.0, -1.0):
            f, rate, stored, loss = _law(sign * Z_MAX, sign * v)
            assert (f, rate) == (pytest.approx(sign * F_HOLD), 0.0)
            assert stored == pytest.approx(0.5 * F_HOLD * Z_MAX)
            assert loss == pytest.approx(F_HOLD * v) and loss > 0.0
    # backing off the limit, it deflects back at once; an overshoot falls back at r_slip
    assert _law(Z_MAX, -1e-3)[1] == -1e-3
    f, rate, _, _ = _law(1.5 * Z_MAX, 0.0)
    assert f == pytest.approx(F_HOLD) and rate == pytest.approx(-R_SLIP * 0.5 * Z_MAX)


def _stop(law, z0: float, *, v0: float, t_stop: float, t_end: float, h: float):
    """z and F along a prescribed slide at v0 that decelerates linearly to rest over t_stop,
    integrated with RK4 on z (the table's motion is given, the contact's state follows)."""
    n = int(round(t_end / h))

    def v_at(t: float) -> float:
        return v0 * min(max(1.0 - (t - 0.5 * t_end) / t_stop, 0.0), 1.0)

    z = z0
    for k in range(n):
        t = k * h
        k1 = law(z, v_at(t))[1]
        k2 = law(z + 0.5 * h * k1, v_at(t + 0.5 * h))[1]
        k3 = law(z + 0.5 * h * k2, v_at(t + 0.5 * h))[1]
        k4 = law(z + h * k3, v_at(t + h))[1]
        z += h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    return law(z, 0.0)[0]


def test_a_table_stopping_from_a_slide_is_held_at_the_sliding_force_where_karnopp_lets_go():
    """Deflected: the force at rest is the force held while sliding, F_hold (exactly: the
    deflection stays pinned at z_max while the table slows). The Karnopp contact let its
    asperities go while sliding and catches the table below its release speed with what the
    deflection over the last few um/s adds: a small share of F_hold."""
    v_reg, v_release = 1e-3, 3e-4
    h, t_stop = 1e-5, 2e-3

    def karnopp(z, v):
        return stiction_force.py_func(z, v, F_HOLD, K_S, D_S, R_SLIP, v_reg, v_release)

    held = _stop(_law, 0.0, v0=0.02, t_stop=t_stop, t_end=0.02, h=h)
    assert held == pytest.approx(F_HOLD, rel=1e-9)
    caught = _stop(karnopp, 0.0, v0=0.02, t_stop=t_stop, t_end=0.02, h=h)
    # the deflection gained from v_release to rest: v_release^2 t_stop / (2 v0)
    assert caught == pytest.approx(K_S * v_release**2 * t_stop / (2.0 * 0.02), rel=0.02)
    assert caught < 0.25 * F_HOLD


def test_a_cycle_dissipates_the_area_of_its_parallelogram():
    """Driven x = X sin(w t) with d_s = 0, the force against displacement is a parallelogram
    (presliding over 2 z_max, sliding at +-F_hold over the rest): the loss over one period is
    its area 4 F_hold (X - z_max), and the loss power is not negative."""
    X, w = 5.0 * Z_MAX, 2.0 * np.pi
    h = 1e-5
    # at x = 0 rising, on the cycle: the contact has slid up since x = -X + 2 z_max
    z, lost, worst = Z_MAX, 0.0, 0.0
    for k in range(int(round(1.0 / h))):
        t = k * h
        # the state follows the table; with d_s = 0 the law is rate-independent: Euler is exact
        # to O(h) in the switch, plenty at 1e5 steps
        v = X * w * np.cos(w * (t + 0.5 * h))
        f, rate, _, loss = _law(z, v, d_s=0.0)
        lost += loss * h
        worst = min(worst, loss)
        z += rate * h
    assert lost == pytest.approx(4.0 * F_HOLD * (X - Z_MAX), rel=0.01)
    # never negative but for a step that overshot z_max and backs off at F_hold before it has
    # fallen back (1e-5 of the peak power here)
    assert worst >= -1e-4 * F_HOLD * X * w


def test_in_the_engine_a_table_is_held_slides_at_the_holding_force_and_stops_holding_the_drive():
    """A 20 kg table on the contact (k_s as the workflow sets it: the table rings at 0.5 / h),
    pushed by a force source with 0.6 F_hold (held: deflected 0.6 z_max, still), then 1.5 F_hold
    (slides: accelerates at 0.5 F_hold / m exactly, the contact carrying F_hold), then 0.6 F_hold
    again (decelerates at 0.4 F_hold / m, stops and is held with the drive's 0.6 F_hold); the
    drive's work equals the friction's loss plus the energy stored at the end."""
    m, f_hold, h = 20.0, 50.0, 1e-3
    k_s = m * (0.5 / h) ** 2
    contact = {"F_hold": f_hold, "k_s": k_s, "d_s": math.sqrt(k_s * m), "r_slip": 1.0 / h}
    source = {"domain": "translational", "gain": 1.0, "T_lag": 0.0, "f_max": 1e6}
    plant = load_plant(
        {
            "components": [
                {"name": "table", "type": "Mass", "params": {"m": m}},
                {"name": "contact", "type": "ElastoPlasticFriction", "params": contact},
                {"name": "drive", "type": "EffortSource", "params": source},
            ],
            "connect": [["table.flange", "contact.flange"], ["table.flange", "drive.flange"]],
        },
        source="contact",
    ).with_energy_tracking()
    effort = np.r_[np.full(500, 0.6), np.full(500, 1.5), np.full(2000, 0.6)] * f_hold
    drive = np.zeros((len(effort), sig.OUT_SIZE))
    drive[:, sig.OUT_EFFORT_CMD] = effort
    drive[:, sig.OUT_ENABLED] = 1.0
    engine = Engine(plant, base_period_s=h)
    res = engine.run(len(effort), drive=drive)
    s, v, f = res["table.s"], res["table.v"], res["contact.force"]
    assert s[100:500] == pytest.approx(0.6 * f_hold / k_s, rel=1e-6)
    assert f[499] == pytest.approx(0.6 * f_hold, rel=1e-9)
    sliding = slice(600, 1000)
    assert f[sliding] == pytest.approx(f_hold, rel=1e-9)
    assert np.gradient(v, h)[sliding] == pytest.approx(0.5 * f_hold / m, rel=1e-6)
    # it comes to rest (its speed's first zero; the presliding spring then rings out at 0.5 / h)
    stop = 1000 + int(np.argmax(v[1000:] <= 0.0))
    assert (stop - 1000) * h == pytest.approx(v[999] / (0.4 * f_hold / m), abs=2 * h)
    assert f[-1] == pytest.approx(0.6 * f_hold, rel=1e-9) and np.ptp(s[-1000:]) == 0.0
    energy = {n: engine.x[plant.state_index[n]] for n in plant.state_names if "energy." in n}
    stored = res["stored.contact.asperities"][-1] + res["stored.table.kinetic"][-1]
    work, lost = energy["energy.drive.drive"], energy["energy.contact.friction"]
    assert work - lost - stored == pytest.approx(0.0, abs=1e-5 * work)
    assert np.min(res["contact.power.friction"]) >= 0.0


@pytest.mark.parametrize(
    ("field", "value"),
    [("F_hold", -1.0), ("k_s", 0.0), ("d_s", -1.0), ("r_slip", 0.0)],
)
def test_bad_parameters_are_refused_by_name(field, value):
    good = {"F_hold": F_HOLD, "k_s": K_S, "d_s": D_S, "r_slip": R_SLIP}
    with pytest.raises(ValueError, match=field) as info:
        ElastoPlasticFriction(**(good | {field: value}))
    assert str(value) in str(info.value) or f"{value:g}" in str(info.value)
