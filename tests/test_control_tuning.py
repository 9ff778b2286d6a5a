"""Tuning rules and loop margins against analytic values of known loops."""

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from feed_twin.control import tune_cli
from feed_twin.control.loop_response import closed, closed_loop_bandwidth, loop_margins
from feed_twin.control.tuning import (
    LoadMode,
    estimator_delay,
    tune_current_loop,
    tune_position_loop,
    tune_velocity_loop,
)
from feed_twin.core.config import load_yaml

FIXTURES = Path(__file__).parent / "fixtures"


def test_margins_of_an_integrator_with_dead_time():
    K, Td = 120.0, 1.3e-3
    m = loop_margins(lambda s: K * np.exp(-s * Td) / s)
    assert m.crossover_rad_s == pytest.approx(K, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(90.0 - math.degrees(K * Td), rel=1e-9)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / (2 * Td), rel=1e-9)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(math.pi / (2 * Td * K)), rel=1e-9)


def test_margins_of_a_triple_lag_and_of_a_loop_that_never_reaches_minus_180():
    K, T = 4.0, 0.01
    m = loop_margins(lambda s: K / (1 + s * T) ** 3)
    assert m.phase_crossover_rad_s == pytest.approx(math.sqrt(3) / T, rel=1e-9)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(8 / K), rel=1e-9)
    w_c = math.sqrt(K ** (2 / 3) - 1) / T
    assert m.crossover_rad_s == pytest.approx(w_c, rel=1e-9)
    assert m.phase_margin_deg == pytest.approx(180 - 3 * math.degrees(math.atan(w_c * T)), rel=1e-9)
    m2 = loop_margins(lambda s: 50.0 / (s * (1 + 0.01 * s)))
    w2 = math.sqrt((-1 + math.sqrt(1 + 4 * (50 * 0.01) ** 2)) / 2) / 0.01
    assert m2.phase_margin_deg == pytest.approx(90 - math.degrees(math.atan(w2 * 0.01)), rel=1e-9)
    assert m2.gain_margin_db == math.inf and math.isnan(m2.phase_crossover_rad_s)


def test_closed_loop_bandwidth_of_a_first_order_loop():
    assert closed_loop_bandwidth(closed(lambda s: 300.0 / s)) == pytest.approx(300.0, rel=1e-9)


def test_technical_optimum_with_dead_time_has_its_analytic_margins():
    R, L, T = 0.35, 4e-3, 62.5e-6
    d = tune_current_loop(R_s=R, L=L, period_s=T)
    T_sigma = 1.5 * T
    assert d.Kp_V_A == pytest.approx(L / (2 * T_sigma)) and d.Ti_s == pytest.approx(L / R)
    # with the pole cancelled, L(s) = e^{-s T_sigma} / (2 T_sigma s): crossover 1/(2 T_sigma),
    # phase margin 90 deg - 0.5 rad, gain margin pi (phase crossover at pi / (2 T_sigma))
    assert d.margins.crossover_rad_s == pytest.approx(1 / (2 * T_sigma), rel=1e-9)
    assert d.margins.phase_margin_deg == pytest.approx(90 - math.degrees(0.5), rel=1e-9)
    assert d.margins.gain_margin_db == pytest.approx(20 * math.log10(math.pi), rel=1e-9)
    # the dead time delays the response by T_sigma; a first-order loop of time constant
    # 2 T_sigma behind it would need 2 T_sigma ln 10 more, the feedback of the delay is faster
    assert T_sigma < d.rise_time_90_s < 2 * T_sigma * math.log(10) + T_sigma
    wanted = tune_current_loop(R_s=R, L=L, period_s=T, bandwidth_hz=500.0)
    assert wanted.margins.crossover_rad_s == pytest.approx(2 * math.pi * 500.0, rel=1e-9)


def test_symmetric_optimum_gives_its_textbook_margin_on_the_textbook_loop():
    J, K_t, lead, T_v, T_ci = 5.8e-3, 1.9, 0.01, 125e-6, 187.5e-6
    est = estimator_delay((0.5, 0.5), None, T_v)
    assert est == pytest.approx(0.5 * T_v + 0.5 * T_v)
    for a in (2.0, 3.0):
        d = tune_velocity_loop(
            J_total_kg_m2=J,
            K_t=K_t,
            lead_m=lead,
            period_s=T_v,
            T_current_s=T_ci,
            estimator_delay_s=est,
            a=a,
        )
        T_sigma = T_ci + 0.5 * T_v + est
        assert d.T_sigma_s == pytest.approx(T_sigma)
        Kp_rad = d.Kp * lead / (2 * math.pi)
        # textbook: PI * 1/(1 + s T_sigma) * K_t/(J s): PM = atan((a^2-1)/(2a)) at 1/(a T_sigma)
        textbook = loop_margins(
            lambda s, Kp_rad=Kp_rad, d=d, T_sigma=T_sigma: (
                Kp_rad * (1 + 1 / (s * d.Ti_s)) / (1 + s * T_sigma) * K_t / (J * s)
            )
        )
        assert textbook.crossover_rad_s == pytest.approx(1 / (a * T_sigma), rel=1e-9)
        assert textbook.phase_margin_deg == pytest.approx(
            math.degrees(math.atan((a * a - 1) / (2 * a))), rel=1e-9
        )
    by_crossover = tune_velocity_loop(
        J_total_kg_m2=J,
        K_t=K_t,
        lead_m=lead,
        period_s=T_v,
        T_current_s=T_ci,
        estimator_delay_s=est,
        crossover_hz=100.0,
    )
    assert by_crossover.crossover_hz == pytest.approx(100.0)


def test_position_design_meets_its_phase_margin():
    d = tune_position_loop(
        velocity_closed_loop=lambda s: 1 / (1 + s / 600.0),
        velocity_bandwidth_hz=600.0 / (2 * math.pi),
        period_s=250e-6,
        phase_margin_deg=75.0,
    )
    assert d.margins.phase_margin_deg == pytest.approx(75.0, abs=1e-3)
    assert 0 < d.Kv_1_s < 600.0


def test_tuning_errors_name_the_value():
    with pytest.raises(ValueError) as err:
        tune_current_loop(R_s=-0.1, L=1e-3, period_s=1e-4)
    assert str(err.value) == "R_s = -0.1: must be > 0"
    with pytest.raises(ValueError) as err:
        tune_velocity_loop(
            J_total_kg_m2=1e-3,
            K_t=1.0,
            lead_m=0.01,
            period_s=1e-3,
            T_current_s=0.0,
            estimator_delay_s=1e-3,
            crossover_hz=500.0,
        )
    assert str(err.value).startswith("crossover_hz = 500.0: too high for the loop's delays")
    with pytest.raises(ValueError, match=r"phase_margin_deg = 95.0: must lie in \(0, 90\)"):
        tune_position_loop(
            velocity_closed_loop=lambda s: 1 + 0 * s,
            velocity_bandwidth_hz=10.0,
            period_s=1e-3,
            phase_margin_deg=95.0,
        )


def test_tune_subcommand_prints_gains_and_margins(capsys):
    args = argparse.Namespace(
        config=str(FIXTURES / "controller_axis.yaml"), load_mode_hz=None, load_mode_zeta=0.03
    )
    code = tune_cli.main(args)
    assert code == 0
    text = capsys.readouterr().out
    assert "current  design    Kp = 21.33 V/A" in text
    assert "velocity design    Kp = 2557 A s/m" in text
    # the configured gains beside their margins, each with its unit
    assert "current  configured Kp = 21.33 V/A, Ti = " in text
    assert "velocity configured Kp = " in text and " A s/m" in text
    kv = load_yaml(FIXTURES / "controller_axis.yaml")["controller"]["position"]["Kv_1_s"]
    assert f"position configured Kv = {kv:.4g} 1/s; PM" in text


def test_tune_subcommand_reports_config_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("plant: {}\n")
    args = argparse.Namespace(config=str(bad), load_mode_hz=None, load_mode_zeta=0.03)
    assert tune_cli.main(args) == 2
    assert capsys.readouterr().err == f"feed-twin tune: {bad}: no controller section\n"


def test_load_mode_limits_kv_to_its_damping_with_the_asked_gain_margin():
    mode = LoadMode(frequency_hz=120.0, zeta=0.03)
    d = tune_position_loop(
        velocity_closed_loop=lambda s: 1.0 + 0.0 * s,
        velocity_bandwidth_hz=500.0,
        period_s=1e-9,  # no sampling delay: the mode alone sets the phase crossover
        load_mode=mode,
        mode_gain_margin=2.0,
    )
    w0 = 2 * math.pi * 120.0
    assert d.limited_by == "load mode"
    assert d.Kv_1_s == pytest.approx(2 * 0.03 * w0 / 2.0, rel=1e-12)
    # Kv/s * w0^2/(s^2 + 2 zeta w0 s + w0^2) reaches -180 deg at w0, where |L| = Kv/(2 zeta w0)
    assert d.margins.phase_crossover_rad_s == pytest.approx(w0, rel=1e-6)
    assert d.margins.gain_margin_db == pytest.approx(20 * math.log10(2.0), rel=1e-6)
    with pytest.raises(ValueError, match=r"zeta = 1.5: must lie in \(0, 1\)"):
        LoadMode(frequency_hz=100.0, zeta=1.5)
    with pytest.raises(ValueError, match="mode_gain_margin = 0.5: must be >= 1"):
        tune_position_loop(
            velocity_closed_loop=lambda s: 1.0 + 0.0 * s,
            velocity_bandwidth_hz=500.0,
            period_s=1e-3,
            mode_gain_margin=0.5,
        )


def test_tune_subcommand_with_a_load_mode(capsys):
    args = argparse.Namespace(
        config=str(FIXTURES / "controller_axis.yaml"), load_mode_hz=120.0, load_mode_zeta=0.03
    )
    assert tune_cli.main(args) == 0
    assert "(limited by load mode)" in capsys.readouterr().out
    args.load_mode_hz = -3.0
    assert tune_cli.main(args) == 2
    assert capsys.readouterr().err == "feed-twin tune: frequency_hz = -3.0: must be > 0\n"


def test_velocity_tuning_input_errors():
    kwargs: dict[str, Any] = dict(  # the arguments under test, one changed at a time
        J_total_kg_m2=1e-3,
        K_t=1.0,
        lead_m=0.01,
        period_s=1e-3,
        T_current_s=0.0,
        estimator_delay_s=1e-3,
    )
    with pytest.raises(ValueError) as err:
        tune_velocity_loop(**kwargs, a=0.8)
    assert str(err.value) == "a = 0.8: must be > 1 (a = 2 is the classic symmetric optimum)"
    with pytest.raises(ValueError) as err:
        tune_velocity_loop(**{**kwargs, "K_t": 0.0})
    assert str(err.value) == "K_t = 0.0: must be > 0"
    with pytest.raises(ValueError) as err:
        tune_velocity_loop(**{**kwargs, "T_current_s": -1e-4})
    assert str(err.value) == "T_current_s = -0.0001: must be >= 0"
