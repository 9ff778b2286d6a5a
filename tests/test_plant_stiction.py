"""StictionFriction: the elasto-plastic law, and a table held at rest inside the loop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.diagnose import diagnose
from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.synthetic import Unmodelled, generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured
from feed_twin.plant.effect_api import Motion
from feed_twin.plant.registry import COMPONENT_TYPES
from feed_twin.plant.stiction_friction import StictionFriction, stiction_force

ROOT = Path(__file__).resolve().parents[1]
EMPS = ROOT / "config" / "emps_nominal.yaml"
LAW = stiction_force.py_func
F_HOLD, K_S, D_S, R_SLIP = 20.0, 1e7, 3e4, 1e3
Z_MAX = F_HOLD / K_S


def test_stuck_the_asperities_are_a_damped_spring_that_follows_the_table():
    z, v = 0.4 * Z_MAX, -3e-4
    f, rate, stored, loss = LAW(z, v, F_HOLD, K_S, D_S, R_SLIP)
    assert f == pytest.approx(K_S * z + D_S * v, rel=1e-12)
    assert rate == v
    assert stored == pytest.approx(0.5 * K_S * z * z, rel=1e-12)
    assert loss == pytest.approx(D_S * v * v, rel=1e-12)  # the spring's power is stored


def test_slipping_it_is_a_coulomb_force_that_dissipates_f_hold_times_speed():
    f, rate, _, loss = LAW(Z_MAX, 0.05, F_HOLD, K_S, D_S, R_SLIP)
    assert (f, rate) == (pytest.approx(F_HOLD), 0.0)
    assert loss == pytest.approx(F_HOLD * 0.05)
    # backing off the other way, the contact deflects back at once (no delay at a reversal)
    f, rate, _, _ = LAW(Z_MAX, -0.05, F_HOLD, K_S, D_S, R_SLIP)
    assert f == pytest.approx(F_HOLD) and rate == -0.05


def test_an_overshoot_past_the_holding_deflection_falls_back_at_r_slip():
    excess = 1e-7
    f, rate, _, _ = LAW(-Z_MAX - excess, -0.05, F_HOLD, K_S, D_S, R_SLIP)
    assert f == pytest.approx(-F_HOLD)
    assert rate == pytest.approx(R_SLIP * excess, rel=1e-9)


def test_parameters_are_checked_by_name():
    with pytest.raises(ValueError, match="k_s"):
        StictionFriction(F_hold=1.0, k_s=0.0, d_s=0.0, r_slip=1.0)
    with pytest.raises(ValueError, match="F_hold"):
        StictionFriction(F_hold=-1.0, k_s=1.0, d_s=0.0, r_slip=1.0)


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
    assert naming == ["plant/registry.py", "plant/stiction_friction.py"]
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
    signature = BY_NAME["stiction"].signature
    assert signature is not None
    regs = signature(_stops_motion(with_command=True))
    dwell, reversal = slice(305, 495), slice(802, 818)
    assert regs["held"][dwell] == pytest.approx(1.0)  # after the +20 mm/s leg
    assert regs["stuck"][dwell] == pytest.approx(0.0)
    # after the -20 mm/s leg: the command rests on 2 of the 21 samples the table stands
    assert regs["stuck"][reversal] == pytest.approx(-19 / 21)
    assert regs["held"][reversal] == pytest.approx(-2 / 21)
    alone = signature(_stops_motion(with_command=False))
    assert set(alone) == {"held"}
    assert alone["held"] == pytest.approx(regs["held"] + regs["stuck"])
    assert np.abs(alone["held"][:300]).max() < 1e-12  # moving: nothing held


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
    and the drive keeps a force below F_hold; a smoothed Coulomb friction of the same size lets
    it creep towards the command (hundreds of nm per 70 ms), the drive holding almost nothing."""
    nominal = ModelDoc.load(EMPS)
    exact = Unmodelled(effort_noise_std=0.0, current_lag_s=0.0, coupling_stiffness_factor=1.0)
    held = generate(nominal, {"stiction": {"F_hold_N": F_HOLD}}, unmodelled=exact)
    crept = generate(nominal, {"coulomb_friction": {"F_c_N": F_HOLD}}, unmodelled=exact)
    gain = nominal.reference_gain
    assert gain is not None, "emps_nominal.yaml's record has a reference gain"
    rests = list(_rests(held, gain))
    assert len(rests) == 3
    for effort, x in rests:
        assert 5.0 < abs(effort.mean()) < F_HOLD
        assert np.ptp(effort) < 1e-3 * F_HOLD
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
