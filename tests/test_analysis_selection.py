"""Selection of the rivals of one round and the test of a channel that dominates
(analysis.rounds.information, analysis.significance.compare)."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.analysis.effects import motion_from_position
from feed_twin.analysis.plausible import outside_record
from feed_twin.analysis.rounds import PARAMETER_PRICE, effective_counts, information
from feed_twin.analysis.significance import compare

N = 6000


def _smooth(rng: np.random.Generator, size: float) -> np.ndarray:
    """A smooth model error (a few dozen effective samples) of RMS about `size`."""
    t = np.linspace(0.0, 1.0, N)
    phases = rng.uniform(0, 2 * np.pi, 8)
    wave = np.sum([np.sin(2 * np.pi * (k + 1) * t + p) for k, p in enumerate(phases)], axis=0)
    return size * wave / np.std(wave)


def test_an_effect_that_removes_most_of_one_channel_is_not_vetoed_by_a_little_of_another():
    """98 % of the position residual (smooth, far above its noise) removed, the effort (white)
    14 % worse: the sum over channels is negative, the position channel decides."""
    rng = np.random.default_rng(1)
    position = _smooth(rng, 950.0)
    effort = rng.normal(0.0, 1.0, N)
    after_position = position * np.sqrt(0.02)
    after_effort = effort * np.sqrt(1.14)
    before = {"position": position, "effort": effort}
    after = {"position": after_position, "effort": after_effort}
    v = compare(before, after, added=2, own="position")
    assert v.significant and v.dominant == "position", v.words()
    assert v.explained["position"] == pytest.approx(0.98)
    assert v.explained["effort"] == pytest.approx(-0.14)
    assert "in the position channel, which it dominates" in v.words()


@pytest.mark.parametrize(
    ("position_share", "effort_worse"),
    [(0.4, 0.14), (0.6, 0.7)],  # not dominant; dominant but costs more than it removes
)
def test_a_dominant_channel_needs_most_of_its_residual_and_a_net_gain(position_share, effort_worse):
    rng = np.random.default_rng(2)
    position = _smooth(rng, 950.0)
    effort = rng.normal(0.0, 1.0, N)
    before = {"position": position, "effort": effort}
    after = {
        "position": position * np.sqrt(1.0 - position_share),
        "effort": effort * np.sqrt(1.0 + effort_worse),
    }
    v = compare(before, after, added=1, own="position")
    assert not v.significant and v.dominant == "", v.words()


def test_a_two_parameter_effect_that_fits_much_better_outranks_a_one_parameter_one():
    """The issue's costs: asymmetric friction 2389, a constant force 3515 (from 10000). Per
    added degree of freedom the force won (6485/1/3515 > 7611/2/2389)."""
    rng = np.random.default_rng(3)
    effort = rng.normal(0.0, 1.0, N)
    before = {"effort": effort}
    force = {"effort": effort * np.sqrt(0.3515)}
    asymmetric = {"effort": effort * np.sqrt(0.2389)}
    counts = effective_counts(asymmetric)
    assert counts["effort"] == pytest.approx(N, rel=0.1)  # white: every sample counts
    assert information(before, asymmetric, counts, 2) > information(before, force, counts, 1)
    assert information(before, force, counts, 1) == pytest.approx(
        counts["effort"] * np.log(1 / 0.3515) - PARAMETER_PRICE
    )
    assert pytest.approx(10.83, abs=0.01) == PARAMETER_PRICE  # chi^2(1) at 1e-3


def test_of_two_rivals_that_fit_alike_the_one_with_fewer_parameters_ranks_first():
    rng = np.random.default_rng(4)
    effort = rng.normal(0.0, 1.0, N)
    before = {"effort": 10.0 * effort}
    coulomb = {"effort": effort}
    stribeck = {"effort": effort * (1.0 - 1e-6)}  # the same fit, one parameter more
    counts = effective_counts(coulomb)
    assert information(before, coulomb, counts, 1) > information(before, stribeck, counts, 2)


def test_a_stribeck_law_above_every_speed_of_the_record_is_no_finding():
    t = np.linspace(0.0, 2.0, 2001)
    x = 0.01 * np.sin(np.pi * t)
    motion = motion_from_position(
        t, x, effort_sim=None, lead_m=None, pole_pairs=None, travel_m=0.02
    )
    v_max = float(np.max(np.abs(motion.v_m_s)))
    assert (
        outside_record("stribeck_friction", {"dF_s_N": 15.0, "v_s_m_s": 0.5 * v_max}, motion)
        is None
    )
    why = outside_record("stribeck_friction", {"dF_s_N": 15.0, "v_s_m_s": 1.13}, motion)
    assert why == (
        "stribeck_friction was fitted with a Stribeck speed of 1.13 m/s, above every speed of "
        f"the record (at most {v_max:.3g} m/s): not a Stribeck law"
    )


def _candidate(name: str, domain: str, share: float):
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.ranking import Candidate

    return Candidate(
        effect=BY_NAME[name],
        variant="",
        explained_fraction=share,
        f_statistic=100.0,
        p_value=1e-9,
        n_eff=100.0,
        coefficients={},
        significant=True,
        domain=domain,
    )


def test_the_leader_of_every_residual_is_fitted_beside_the_leading_rivals():
    """Three timings of the record take 98 % of the position residual; a feedback delay in the
    loop 27 % of the effort's: shares of different residuals do not compare, so it is fitted
    too (the truth machine's 4 ms feedback delay was named a command delay)."""
    from feed_twin.analysis.rounds import Options, choose_rivals

    ranked = [
        _candidate("trace_window", "position", 0.98),
        _candidate("position_delay", "position", 0.98),
        _candidate("lead_error", "position", 0.97),
        _candidate("backlash", "position", 0.46),
        _candidate("measurement_delay", "effort", 0.27),
        _candidate("channel_delay", "effort", 0.27),
    ]
    chosen = [c.name for c in choose_rivals(ranked, Options())]
    assert chosen == ["trace_window", "position_delay", "lead_error", "measurement_delay"]
    # within one residual the share still decides: one rival at half the leader's share
    chosen = [c.name for c in choose_rivals(ranked[2:5], Options())]
    assert chosen == ["lead_error", "measurement_delay"]


def test_a_support_that_is_nearly_the_whole_record_is_judged_as_the_record():
    """A screw's heating grows with the distance travelled, from the first motion on: its
    signature's support is the record less its first rest. On a smooth record (the position
    residual of a 1 kHz trace: a handful of effective samples) that support has as few as the
    record itself, which is the record's limit, not the support's: the growth, 9/10 of the
    residual, is fitted (the truth machine's 1.48 K/m heating at seed 102 never was). A support
    of a few samples in a record of many still gives no noise level of its own."""
    from feed_twin.analysis.ranking import MIN_SUPPORT_N_EFF, rank, supported

    t = np.linspace(0.0, 10.0, 10001)
    x = 0.2 + 0.15 * (1.0 - np.cos(np.pi * np.clip(t - 0.1, 0.0, None)))  # rests 0.1 s, moves
    motion = motion_from_position(t, x, effort_sim=None, lead_m=None, pole_pairs=None, travel_m=0.3)
    travelled = np.cumsum(np.abs(motion.v_m_s) * np.gradient(t))
    growth = -11.5e-6 * 1.5 * travelled * (0.1 + x)  # 1.5 K/m on a screw 0.1 m from its bearing
    error = 0.3 * float(np.std(growth)) * np.sin(2.0 * np.pi * 0.15 * t)  # a smooth model error
    ranking = rank(motion, effort_residual=None, position_residual=growth + error)
    thermal = next(c for c in ranking if c.name == "thermal_drift")
    assert thermal.support is not None and 0.95 < float(np.mean(thermal.support)) < 1.0
    assert thermal.n_eff < MIN_SUPPORT_N_EFF  # too few for a support of its own ...
    assert thermal.support_counts and thermal.worth_fitting  # ... but they are the record's
    assert thermal.support_fraction > 0.85
    assert ranking[0].name == "thermal_drift"
    few = np.zeros(10001, dtype=bool)
    few[:300] = True
    assert not supported(few, 4.0, 400.0)  # a few samples in a record of many
    assert supported(few, 12.0, 400.0) and supported(None, 1.0, 400.0)


def test_a_rival_on_its_fallback_residual_leaves_a_place_for_that_residuals_own_leader():
    """Without voltages the dead time is ranked on the effort (its fallback) and took 53 % of
    it, the effort's one place beside the record's timings; the truth machine's 4 ms feedback
    delay (24 % of the effort, measurement_delay's own residual) was then never fitted and the
    delay was named a command delay. The best effect ranked on its own residual is fitted too;
    one that already has a place is not fitted twice."""
    from feed_twin.analysis.rounds import Options, choose_rivals

    ranked = [
        _candidate("command_delay", "position", 0.98),
        _candidate("position_delay", "position", 0.98),
        _candidate("dead_time", "effort", 0.53),
        _candidate("channel_delay", "effort", 0.30),
        _candidate("measurement_delay", "effort", 0.24),
    ]
    chosen = [c.name for c in choose_rivals(ranked, Options())]
    assert chosen == ["command_delay", "position_delay", "dead_time", "channel_delay"]
    # channel_delay is ranked on the effort as its own; without it the next such one is fitted
    chosen = [c.name for c in choose_rivals(ranked[:3] + ranked[4:], Options())]
    assert chosen == ["command_delay", "position_delay", "dead_time", "measurement_delay"]
    # ranked on its own residual (a recorded q-voltage) the dead time takes the place alone
    alone = [_candidate("dead_time", "voltage", 0.9), _candidate("constant_force", "effort", 0.5)]
    assert [c.name for c in choose_rivals(alone, Options())] == ["dead_time", "constant_force"]
