"""What a record can show: resolution from the values, staircases of rounding smoothed, and the
effects a slow, coarse record cannot show listed with their reasons."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from feed_twin.analysis.rounding import dequantize, resolution, staircase_fraction
from feed_twin.analysis.visibility import Unseen, Visibility, with_floor


@pytest.mark.parametrize("q", [1e-3, 1e-4, 5e-6, 1e-8])
def test_resolution_is_the_rounding_step(q):
    rng = np.random.default_rng(1)
    x = np.round(rng.uniform(0.05, 0.2, 2000) / q) * q
    assert resolution(x) == pytest.approx(q)


def test_an_unrounded_signal_has_no_resolution():
    x = np.random.default_rng(2).uniform(0.0, 1.0, 1000)
    assert resolution(x) == 0.0


def test_staircase_smoothed_through_the_midpoints_of_its_steps():
    """A slow ramp (2 mm/s) rounded to 1 mm at 10 Hz stands still 4 samples of 5: smoothed, it
    is the ramp again to within a tenth of the step (the midpoints are exact crossings, up to
    half a sample of timing)."""
    h, q, v = 0.1, 1e-3, 2e-3
    t = h * np.arange(200)
    true = np.where(t < 2.0, 0.1, 0.1 + v * (t - 2.0))
    true = np.where(t > 15.0, 0.1 + v * 13.0, true)
    rounded = np.round(true / q) * q
    assert staircase_fraction(rounded, q) > 0.7
    smooth = dequantize(t, rounded, q)
    moving = (t > 3.0) & (t < 14.0)
    assert np.max(np.abs(smooth - true)[moving]) < 0.15 * q
    assert np.max(np.abs(rounded - true)[moving]) > 0.35 * q  # what the twin got before
    assert smooth[0] == pytest.approx(0.1) and smooth[-1] == pytest.approx(rounded[-1])


def test_fast_moves_keep_their_samples():
    t = 0.1 * np.arange(100)
    x = np.round(0.05 * t / 1e-3) * 1e-3  # 5 mm per sample: no staircase
    assert staircase_fraction(x, 1e-3) == 0.0
    assert np.allclose(dequantize(t, x, 1e-3), x)


def test_floors_raised_to_the_rounding_noise():
    vis = Visibility(
        sample_period_s=0.1,
        position_resolution_m=1e-3,
        effort_resolution=0.01,
        fe_expected_max_m=4e-5,
        position_evidence=False,
        velocity_resolution_m_s=1e-2,
        unseen=(Unseen(name="backlash", reason="below the resolution"),),
    )
    floors = with_floor({"position": 1e-9, "effort": 0.5}, vis)
    assert floors["position"] == pytest.approx(100 * 1e-3)  # no evidence: no say
    with_evidence = dataclasses.replace(vis, position_evidence=True)
    assert with_floor({"position": 1e-9}, with_evidence)["position"] == pytest.approx(
        1e-3 / math.sqrt(12.0)
    )
    assert floors["effort"] == 0.5
    lines = vis.lines()
    assert lines[0] == (
        "record: 10 Hz, position resolution 1 mm, following error of the nominal twin up to 40 um"
    )
    assert "cannot be seen in this record: backlash: below the resolution" in lines


def test_force_constant_against_friction_and_weight_is_said():
    from types import SimpleNamespace

    from feed_twin.analysis.fit import SimOutputs
    from feed_twin.analysis.visibility import force_constant_correlation

    t = np.linspace(0.0, 10.0, 1001)
    v = 0.1 * np.sin(2.0 * math.pi * t / 5.0)
    run = SimpleNamespace(effort_name="force_cmd_N")
    friction_only = 100.0 * np.tanh(v / 0.005) + 300.0 * v - 50.0
    out = SimOutputs(x_m=t[None, :], effort=friction_only[None, :], ok=np.ones(1, bool))
    line = force_constant_correlation(run, out, v)  # type: ignore[arg-type]
    assert line is not None and "nearly one unknown" in line
    inertia = friction_only + 2000.0 * np.gradient(v, t)
    out = SimOutputs(x_m=t[None, :], effort=inertia[None, :], ok=np.ones(1, bool))
    line = force_constant_correlation(run, out, v)  # type: ignore[arg-type]
    assert line is not None and "the accelerations tell them apart" in line


def _viscous_candidate(share: float):
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.ranking import Candidate

    return Candidate(
        effect=BY_NAME["viscous_friction"],
        variant="",
        explained_fraction=share,
        f_statistic=20.0,
        p_value=1e-5,
        n_eff=500.0,
        coefficients={"v": 0.5},
        significant=False,
        force_per_unit=262.0,  # [N per N m]: 0.5 N m s/m is 131 N s/m
    )


def test_a_visible_viscous_friction_too_small_to_name_is_said():
    from feed_twin.analysis.visibility import too_small

    vis = Visibility(
        sample_period_s=0.1,
        position_resolution_m=1e-3,
        effort_resolution=0.0,
        fe_expected_max_m=1e-4,
        position_evidence=False,
        velocity_resolution_m_s=0.01,
        unseen=(),
    )
    (said,) = too_small(vis, ["coulomb_friction"], [_viscous_candidate(0.023)])
    assert said.name == "viscous_friction"
    assert said.reason == (
        "not named: its signature explains 2.3 % of the effort residual left (an excess of "
        "about 1.3e+02 N s/m over the model's), under the 5 % an effect must remove: too small "
        "against this record's rounding"
    )
    assert too_small(vis, ["viscous_friction"], [_viscous_candidate(0.023)]) == []
    assert too_small(vis, [], [_viscous_candidate(0.08)]) == []  # large enough: a fit's call


def test_every_delay_of_the_library_is_listed_unseen_on_a_slow_record():
    """Each delay effect is searched within a few base periods, so a 10 Hz record cannot show
    one: the list that visibility refuses on such a record names every delay of the library
    (command_delay was missing and was named on two 1 mm, 10 Hz records of the slow-record
    benchmark)."""
    from feed_twin.analysis.effects import LIBRARY
    from feed_twin.analysis.visibility import DELAY_EFFECTS

    delays = {e.name for e in LIBRARY if e.name.endswith("_delay")}
    assert delays, "the library has delay effects"
    assert delays <= set(DELAY_EFFECTS)
