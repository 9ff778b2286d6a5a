"""StictionFriction: the elasto-plastic law, and a table held at rest inside the loop."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.synthetic import Unmodelled, generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.core.smooth import smooth_sign
from feed_twin.io.measured import load_measured
from feed_twin.plant.effect_api import Motion
from feed_twin.plant.registry import COMPONENT_TYPES
from feed_twin.plant.stiction_evidence import HOLD_MIN_S, held_share, held_stops
from feed_twin.plant.stiction_friction import DEFLECTED_SHARE, StictionFriction, stiction_force

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"
LAW = stiction_force.py_func
F_HOLD, K_S, D_S, R_SLIP = 20.0, 1e7, 3e4, 1e3
V_REG, V_RELEASE = 1e-3, 1e-4
Z_MAX = F_HOLD / K_S


def _law(z: float, v: float):
    return LAW(z, v, F_HOLD, K_S, D_S, R_SLIP, V_REG, V_RELEASE)


def _sliding(v: float) -> float:
    return F_HOLD * smooth_sign.py_func(v, V_REG)


def test_stuck_the_asperities_are_a_damped_spring_that_follows_the_table():
    z, v = 0.4 * Z_MAX, -3e-5
    f, rate, stored, loss = _law(z, v)
    assert f == pytest.approx(_sliding(v) + K_S * z + D_S * v, rel=1e-12)
    assert rate == v
    assert stored == pytest.approx(0.5 * K_S * z * z, rel=1e-12)
    # the spring's power is stored: what is lost is the damping's and the sliding law's
    assert loss == pytest.approx(D_S * v * v + _sliding(v) * v, rel=1e-12)


def test_breaking_away_below_the_release_speed_it_is_dragged_at_the_holding_force():
    v = 0.5 * V_RELEASE
    f, rate, _, loss = _law(Z_MAX, v)
    assert (f, rate) == (pytest.approx(F_HOLD + _sliding(v)), 0.0)
    assert loss == pytest.approx(f * v)
    # backing off the other way, the contact deflects back at once (no delay at a reversal)
    f, rate, _, _ = _law(Z_MAX, -v)
    assert f == pytest.approx(F_HOLD + _sliding(-v)) and rate == -v


def test_sliding_the_asperities_let_go_and_the_force_is_the_regularised_coulomb_force():
    z = 0.7 * Z_MAX
    f, rate, _, _ = _law(z, 0.05)
    assert f == pytest.approx(F_HOLD + K_S * z)  # sgn(0.05 / 1e-3) = 1
    assert rate == pytest.approx(-R_SLIP * z)
    f, rate, _, loss = _law(0.0, 0.05)
    assert (f, rate) == (pytest.approx(F_HOLD), 0.0)
    assert loss == pytest.approx(F_HOLD * 0.05)  # a Coulomb force dissipates F v
    # at the release speed the sliding law has fallen to a tenth of F_hold: the break-away drop
    assert _sliding(V_RELEASE) == pytest.approx(0.1 * F_HOLD, rel=0.01)


def test_an_overshoot_past_the_holding_deflection_falls_back_at_r_slip():
    excess = 1e-7
    f, rate, _, _ = _law(-Z_MAX - excess, -0.5 * V_RELEASE)
    assert f == pytest.approx(-F_HOLD + _sliding(-0.5 * V_RELEASE))
    assert rate == pytest.approx(R_SLIP * excess, rel=1e-9)


def _pushed(m: float, push_rate: float, h: float, steps: int):
    """A mass m [kg] on the law under a force rising at push_rate [N/s] from rest (RK4 of
    step h): (time, position, speed, friction force) at each step."""

    def rhs(y, t):
        f, rate, _, _ = _law(y[2], y[1])
        return np.array([y[1], (push_rate * t - f) / m, rate])

    y, out = np.zeros(3), []
    for k in range(steps):
        t = k * h
        k1 = rhs(y, t)
        k2 = rhs(y + 0.5 * h * k1, t + 0.5 * h)
        k3 = rhs(y + 0.5 * h * k2, t + 0.5 * h)
        k4 = rhs(y + h * k3, t + h)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append((t + h, y[0], y[1], _law(y[2], y[1])[0]))
    return np.array(out)


def test_a_pushed_table_stays_until_the_holding_force_then_breaks_away_as_karnopps():
    """Karnopp's table: at rest while the force on it stays below F_hold (here on the asperity
    spring, F / k_s, damped), then it breaks away and the friction falls to the sliding law's,
    so the table lurches. A force rising at 200 N/s on 10 kg reaches F_hold at 0.1 s."""
    m, push, h = 10.0, 200.0, 2e-5
    run = _pushed(m, push, h, 7000)
    t, x, v, f = run.T
    before = t < 0.095
    # quasi-static on the spring, less what the damping and the sliding law's slope (1 / v_reg)
    # take at the creep speed push / k_s
    lag = (D_S + F_HOLD / V_REG) * (push / K_S) / K_S
    assert np.all(np.abs(x[before] - push * t[before] / K_S) < 1.05 * lag)
    assert lag < 0.06 * Z_MAX
    assert np.all(np.abs(v[before]) < V_RELEASE)
    away = int(np.argmax(np.abs(v) >= V_RELEASE))
    assert 0.099 < t[away] < 0.1 + 0.15 * F_HOLD / push  # a few per cent above F_hold
    # the asperities let go (at r_slip, 1 / ms): 10 ms on, the friction is the sliding law's
    later = away + int(10e-3 / h)
    assert f[later] == pytest.approx(_sliding(v[later]), rel=1e-3)
    assert f[later] < 0.9 * push * t[later]  # the force on it exceeds the friction: it lurches


def test_parameters_are_checked_by_name():
    ok = {"F_hold": 1.0, "k_s": 1.0, "d_s": 0.0, "r_slip": 1.0, "v_reg": 1e-3, "v_release": 1e-4}
    for name, bad in (("k_s", 0.0), ("F_hold", -1.0), ("v_reg", 0.0), ("v_release", -1e-4)):
        with pytest.raises(ValueError, match=name):
            StictionFriction(**{**ok, name: bad})


def test_one_component_file_and_one_registry_line_make_a_library_effect():
    assert COMPONENT_TYPES["StictionFriction"] is StictionFriction
    assert BY_NAME["stiction"].owner == "StictionFriction"
    # the law is known nowhere else: not to the analysis, not to the rest of the plant (the
    # independent truth machine, feed_twin/truth, has a sticking law of its own by design)
    package = ROOT / "feed_twin"
    naming = sorted(
        str(path.relative_to(package))
        for path in package.rglob("*.py")
        if ("StictionFriction" in path.read_text() or "stiction" in path.read_text())
        and path.relative_to(package).parts[0] != "truth"
    )
    assert naming == [
        "plant/elastoplastic_friction.py",  # the contact of the "deflected" variant
        "plant/registry.py",
        "plant/stiction_evidence.py",  # where a record holds a table still, and how
        "plant/stiction_friction.py",
    ]
    assert BY_NAME["stiction"].component == "StictionFriction.F_hold"
    assert BY_NAME["stribeck_friction"].component == "GuideFriction.dF_s, v_s"  # the field


def _stops_motion(*, with_command: bool):
    """+20 mm/s for 0.3 s, a 0.2 s dwell, -20 mm/s for 0.3 s; then a reversal whose table
    sticks 20 ms while its command turns through zero speed and moves on (+20 mm/s)."""
    h = 1e-3
    v_cmd = np.r_[np.full(300, 0.02), np.zeros(200), np.full(300, -0.02), np.full(300, 0.02)]
    v_cmd[799:801] = 0.0  # the command turns through zero speed
    v = v_cmd.copy()
    v[800:820] = 0.0  # the table sticks while the command moves on
    t = h * np.arange(len(v), dtype=np.float64)
    return Motion(
        t_s=t, x_m=np.cumsum(v) * h, v_m_s=v, a_m_s2=np.gradient(v, h), effort_sim=None,
        lead_m=None, pole_pairs=None, travel_m=0.1,
        v_cmd_m_s=v_cmd if with_command else None,
    )  # fmt: skip


def test_a_stop_is_held_where_its_command_rests_and_stuck_where_it_moves_on():
    """The signature splits the rest of each stop by the share of it the command rests too:
    at a dwell the table holds the force the loop left (held), at a reversal it is stuck while
    the drive's force swings through the band (stuck); without a command, one regressor."""
    ((label, signature),) = BY_NAME["stiction"].variants(_stops_motion(with_command=True))
    assert label == "held"
    regs = signature(_stops_motion(with_command=True))
    dwell, reversal = slice(305, 495), slice(802, 818)
    assert regs["held"][dwell] == pytest.approx(1.0)  # after the +20 mm/s leg
    assert regs["stuck"][dwell] == pytest.approx(0.0)
    # after the -20 mm/s leg: the command rests on 2 of the 21 samples the table stands
    assert regs["stuck"][reversal] == pytest.approx(-19 / 21)
    assert regs["held"][reversal] == pytest.approx(-2 / 21)
    # the dwell lasts: its own ramp over its rest, 0 at its start, 1 at its end, 0 elsewhere
    # (the 20 ms reversal is too short for the loop's integrator to wind a force up)
    ramps = sorted(k for k in regs if k.startswith("ramp"))
    assert ramps == ["ramp0"]
    ramp = regs["ramp0"]
    assert ramp[300:500].max() == pytest.approx(1.0, abs=0.02)
    assert np.all(np.diff(ramp[305:495]) > 0.0)
    assert np.abs(ramp[:295]).max() == 0.0 and np.abs(ramp[505:]).max() == 0.0
    alone = signature(_stops_motion(with_command=False))
    assert set(alone) == {"held"}
    assert alone["held"] == pytest.approx(regs["held"] + regs["stuck"])
    assert np.abs(alone["held"][:300]).max() < 1e-12  # moving: nothing held


def _stopping(creep_m_s: float, rest_s: float) -> Motion:
    """+20 mm/s for 0.3 s, then at rest for rest_s creeping at creep_m_s, then -20 mm/s for
    0.3 s; the position counted in 10 nm steps, as the truth machine's scale counts it."""
    h = 1e-3
    n_rest = int(round(rest_s / h))
    v = np.r_[np.full(300, 0.02), np.full(n_rest, creep_m_s), np.full(300, -0.02)]
    t = h * np.arange(len(v), dtype=np.float64)
    x = np.round(np.cumsum(v) * h / 1e-8) * 1e-8
    return Motion(
        t_s=t, x_m=x, v_m_s=v, a_m_s2=np.gradient(v, h), effort_sim=None, lead_m=None,
        pole_pairs=None, travel_m=0.1,
    )  # fmt: skip


def test_only_a_table_held_still_is_evidence_of_stiction():
    """A table that stays within a few counts for HOLD_MIN_S is held by friction; one that
    creeps onto its target (a sliding friction: 1 um/s moves it 15 counts in 1.5 HOLD_MIN_S),
    or stands still only as long as a sharp sliding law lets it (0.4 HOLD_MIN_S), is not:
    there the effect has no signature and is not ranked."""
    held = _stopping(0.0, 1.5 * HOLD_MIN_S)
    spans = held_stops(held)
    assert len(spans) == 1
    a, b = spans[0]
    assert held.t_s[a] == pytest.approx(0.3, abs=2e-3)
    assert held.t_s[b - 1] - held.t_s[a] == pytest.approx(1.5 * HOLD_MIN_S, abs=3e-3)
    assert [label for label, _ in BY_NAME["stiction"].variants(held)] == ["held"]
    for creep, rest in ((1e-6, 1.5 * HOLD_MIN_S), (0.0, 0.4 * HOLD_MIN_S)):
        assert held_stops(_stopping(creep, rest)) == []
        assert BY_NAME["stiction"].variants(_stopping(creep, rest)) == []


def test_a_table_still_with_nothing_pushing_it_is_no_evidence_of_stiction():
    """Where the record has an effort, a still table must hold a force the nominal twin does
    not: one resting in a backlash gap stands still as long with nothing pushing it (the
    effort residual is noise there), one held by stiction has its loop's integrator ramp the
    force up (its RMS here 23 times the noise)."""
    still = _stopping(0.0, 1.5 * HOLD_MIN_S)
    noise = np.random.default_rng(3).normal(0.0, 0.01, len(still.t_s))
    rest = (still.t_s >= 0.3) & (still.t_s < 0.3 + 1.5 * HOLD_MIN_S)
    ramp = np.where(rest, 0.4 * (still.t_s - 0.3) / (1.5 * HOLD_MIN_S), 0.0)
    twin = np.zeros_like(still.t_s)
    loose = dataclasses.replace(still, effort_sim=twin, effort_meas=noise)
    held = dataclasses.replace(still, effort_sim=twin, effort_meas=noise + ramp)
    assert held_stops(loose) == [] and BY_NAME["stiction"].variants(loose) == []
    assert len(held_stops(held)) == 1


def _holding_drive(held: float, ramp_to: float) -> Motion:
    """+20 mm/s and +5 mm/s for 0.15 s each, held still for 1.5 HOLD_MIN_S, then -20 and -5
    mm/s (10 nm counts); the drive's effort a weight 30 N + Coulomb 50 N sgn(v) + 2000 N s/m v
    + 150 kg a while moving; at rest it holds 50 N `held` at the stop's start, wound linearly
    to 50 N `ramp_to` at its end; 0.3 N noise."""
    h, n_rest = 1e-3, int(round(1.5 * HOLD_MIN_S / 1e-3))
    v = np.r_[np.full(150, 0.02), np.full(150, 0.005), np.zeros(n_rest)]
    v = np.r_[v, np.full(150, -0.02), np.full(150, -0.005)]
    t = h * np.arange(len(v), dtype=np.float64)
    x = np.round(np.cumsum(v) * h / 1e-8) * 1e-8
    a = np.gradient(v, h)
    rest = (t >= 0.3) & (t < 0.3 + 1.5 * HOLD_MIN_S)
    s = np.where(rest, (t - 0.3) / (1.5 * HOLD_MIN_S), 0.0)
    moving = 30.0 + 50.0 * np.sign(v) + 2000.0 * v + 150.0 * a
    effort = np.where(rest, 30.0 + 50.0 * (held + (ramp_to - held) * s), moving)
    noise = np.random.default_rng(5).normal(0.0, 0.3, len(t))
    return Motion(
        t_s=t, x_m=x, v_m_s=v, a_m_s2=a, effort_sim=np.zeros_like(t), lead_m=None,
        pole_pairs=None, travel_m=0.1, effort_meas=effort + noise,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("held", "ramp_to", "variant"),
    [
        (1.0, 1.0, "deflected"),  # stops deflected: holds the sliding force
        (0.8, 1.1, "deflected"),  # the loop takes a little off, or winds on
        (0.25, -1.0, "held"),  # caught at the release speed, wound to the other break-away
        (0.05, 0.9, "held"),  # caught with nearly nothing, wound up to break away onward
    ],
)
def test_the_contact_is_chosen_by_the_share_of_its_sliding_force_held_at_the_stop(
    held: float, ramp_to: float, variant: str
):
    """The drive that holds its sliding force as its table comes to rest has a contact that
    stops deflected (elasto-plastic, "deflected"); one caught with a small share of it has one
    that let go while sliding (Karnopp, "held"). The share is measured over the stop's first
    quarter against the Coulomb part of the moving effort (its weight, viscous and inertial
    parts split off), whatever the loop's integrator does afterwards."""
    m = _holding_drive(held, ramp_to)
    spans = held_stops(m)
    assert len(spans) == 1
    # the first quarter's mean of the ramp: held + (ramp_to - held) / 8
    share = held_share(m, spans)
    assert share is not None, "the record has an effort and a sliding force"
    assert share == pytest.approx(held + (ramp_to - held) / 8.0, abs=0.02)
    assert [label for label, _ in BY_NAME["stiction"].variants(m)] == [variant]
    assert (share >= DEFLECTED_SHARE) == (variant == "deflected")


def test_without_an_effort_or_a_sliding_force_the_contact_is_karnopps():
    """No effort recorded (the position alone shows the held table) or no sliding force in it:
    nothing tells how the contact stops, and the Karnopp contact is kept."""
    m = _holding_drive(1.0, 1.0)
    spans = held_stops(m)
    assert held_share(dataclasses.replace(m, effort_meas=None), spans) is None
    assert [label for label, _ in BY_NAME["stiction"].variants(
        dataclasses.replace(m, effort_meas=None, effort_sim=None))] == ["held"]  # fmt: skip
    assert m.effort_meas is not None
    # an effort whose part in sign(v) helps the motion along: no sliding force to compare with
    helping = dataclasses.replace(m, effort_meas=-np.abs(m.effort_meas))
    assert held_share(helping, spans) is None


def _rests(columns, gain: float):
    """(effort, table position) over the second half of each dwell longer than 80 ms."""
    x_cmd = columns["x_cmd_mm"] * 1e-3
    still = np.r_[False, np.abs(np.diff(x_cmd)) < 1e-12]
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if b - a > 80:
            half = slice(a + (b - a) // 2, b)
            yield columns["u_drive_V"][half] * gain, columns["x_act_mm"][half] * 1e-3


def test_the_table_is_held_at_rest_where_smoothed_coulomb_friction_creeps():
    """EMPS loop (P position, P velocity): stopped by a holding friction, the table stays put
    and the drive keeps the force it had when the table stuck, below F_hold; a smoothed Coulomb
    friction of the same size lets it creep towards the command (hundreds of nm per 70 ms),
    the drive holding almost nothing. The table slides in on the regularised law until it is
    slower than the release speed (0.3 v_reg), so the force it sticks with is the loop's at
    that speed (5-12 N when the law stopped the table as soon as the drive's force fell below
    F_hold, at any speed; 1.7 N with the release at 0.1 v_reg)."""
    nominal = ModelDoc.load(EMPS)
    exact = Unmodelled(effort_noise_std=0.0, current_lag_s=0.0, coupling_stiffness_factor=1.0)
    held = generate(nominal, {"stiction": {"F_hold_N": F_HOLD}}, unmodelled=exact)
    crept = generate(nominal, {"coulomb_friction": {"F_c_N": F_HOLD}}, unmodelled=exact)
    gain = nominal.reference_gain
    assert gain is not None, "emps_nominal.yaml's record has a reference gain"
    rests = list(_rests(held, gain))
    assert len(rests) == 3
    for effort, x in rests:
        assert 0.07 * F_HOLD < abs(effort.mean()) < F_HOLD
        # held to the encoder's count: the P loop's force steps where the motor's count flips
        assert np.ptp(effort) < 0.02 * F_HOLD
        assert np.ptp(x) < 1e-9
    for effort, x in _rests(crept, gain):
        assert abs(effort.mean()) < 0.05 * F_HOLD
        assert np.ptp(x) > 1e-7


@pytest.mark.slow
def test_stiction_is_named_and_takes_over_the_coulomb_friction_found_first(tmp_path):
    nominal = ModelDoc.load(EMPS)
    columns = generate(nominal, {"stiction": {"F_hold_N": F_HOLD}})
    map_path = write_csv(tmp_path / "run.csv", columns, nominal)
    d = diagnose(load_measured(tmp_path / "run.csv", map_path), nominal)[0]
    assert [e.name for e in d.effects] == ["stiction"], d.notes
    assert d.effects[0].parameters["F_hold_N"] == pytest.approx(F_HOLD, rel=0.05)
    assert any("coulomb_friction was dropped" in n and "collapsed" in n for n in d.notes), d.notes
    after, before = d.after.effort_rms, d.before.effort_rms
    assert after is not None and before is not None, "the record has an effort: RMS values"
    assert after < 0.05 * before
