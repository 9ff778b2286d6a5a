"""The jerk filter's kernels on their own: raw speeds, raw bodies, erosion, the box filter."""

from __future__ import annotations

import numpy as np
import pytest

from feed_twin.gcode.jerk_filter import (
    body_profiles_filtered,
    box_filter,
    erode,
    plan_speeds_filtered,
    raw_samples,
)
from feed_twin.gcode.profile import BODY

T = 0.05  # [s] filter window


def test_raw_speeds_fit_every_body_with_the_held_stretches():
    rng = np.random.default_rng(3)
    m = 40
    L = rng.uniform(1e-4, 2e-2, m)
    A = rng.uniform(0.5, 3.0, m)
    cap = rng.uniform(0.01, 0.3, m + 1)
    cap[-1] = 0.0
    # Holds of T / 2 each side (extended nodes), or of T on one side (held chain ends).
    hold_in = rng.choice([0.0, 0.5 * T, T], m + 1)
    hold_out = rng.choice([0.0, 0.5 * T, T], m + 1)
    v = plan_speeds_filtered(cap, L, A, hold_in, hold_out, 0.0)
    assert v[0] == 0.0 and v[-1] == 0.0 and np.all(v <= cap + 1e-15)
    held_in, held_out = hold_in * v, hold_out * v
    need = np.abs(v[1:] ** 2 - v[:-1] ** 2) / (2.0 * A) + held_out[:-1] + held_in[1:]
    assert np.all(need <= L * (1 + 1e-12))
    # Bodies: they fill their length; a body alone (both ends held on its side) with a peak
    # above both ends cruises at least T at A, or takes at most T in all at A, or runs at
    # A / 2; chain bodies keep their A.
    V = np.full(m, 0.3)
    vp, t_up, t_cruise, t_down, a_used = body_profiles_filtered(v, L, V, A, hold_in, hold_out, T)
    room = L - held_out[:-1] - held_in[1:]
    covered = 0.5 * (v[:-1] + vp) * t_up + vp * t_cruise + 0.5 * (vp + v[1:]) * t_down
    np.testing.assert_allclose(covered, room, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(t_up, (vp - v[:-1]) / a_used, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(t_down, (vp - v[1:]) / a_used, rtol=1e-12, atol=1e-15)
    alone = (hold_out[:-1] > 0.0) & (hold_in[1:] > 0.0)
    peaked = vp > np.maximum(v[:-1], v[1:]) * (1 + 1e-12)
    at_full = alone & peaked & (a_used == A)
    total = t_up + t_cruise + t_down
    assert np.all((t_cruise[at_full] >= T * (1 - 1e-9)) | (total[at_full] <= T))
    assert np.any(at_full & (total <= T) & (t_cruise < T))  # short bodies alone run at A
    assert np.all((a_used == A) | (alone & (a_used == 0.5 * A)))
    assert np.all(vp <= V)


@pytest.mark.parametrize(
    ("length", "a_used", "cruise"),
    [(1e-3, 3.0, 0.0), (3e-3, 1.5, 0.0), (1e-2, 3.0, T)],
    ids=["within-T-at-A", "at-A/2", "cruise-T-at-A"],
)
def test_a_body_alone_takes_the_quickest_profile_no_window_sees_both_signs_of_at_a(
    length, a_used, cruise
):
    # A step-over between two corners crawled at 10 mm/s (held T / 2 on its side each):
    # the 0.5 mm left rise and fall at A within 20 ms < T; 2.5 mm would take 69 ms at A
    # without a cruise, so A / 2 (vp^2 = v^2 + (A / 2) room); 9.5 mm cruise T at A.
    v = np.array([0.01, 0.01])
    held = np.array([0.5 * T, 0.5 * T])
    vp, t_up, t_cruise, t_down, a = body_profiles_filtered(
        v, np.array([length]), np.array([0.3]), np.array([3.0]), held, held, T
    )
    room = length - T * 0.01
    assert a[0] == a_used
    assert t_cruise[0] == pytest.approx(cruise, abs=1e-12)
    if cruise == 0.0:
        assert vp[0] == pytest.approx(np.sqrt(0.01**2 + a_used * room), rel=1e-12)
    assert (t_up[0] + t_down[0] <= T) == (length == 1e-3)


def test_erode_lowers_an_item_to_any_neighbour_within_that_neighbours_reach():
    lo = np.array([0.0, 1.0, 2.0, 5.0, 6.0])
    hi = np.array([1.0, 2.0, 3.0, 6.0, 7.0])
    value = np.array([5.0, 4.0, 1.0, 3.0, 0.5])
    reach = np.array([0.0, 0.0, 1.5, 0.0, 0.0])  # item 2 reaches 1.5 beyond its ends
    group = np.array([0, 0, 0, 0, 1])  # item 4 is another chain
    none = np.zeros(5)
    out = erode(lo, hi, value, reach, group, none, 0.0)
    # Item 0 (gap 1.0) and 1 (touching) take item 2's 1.0; item 3 (gap 2.0) is beyond reach.
    np.testing.assert_array_equal(out, [1.0, 1.0, 1.0, 3.0, 0.5])
    assert erode(lo, hi, value, reach, np.full(5, -1), none, 0.0).tolist() == value.tolist()


def test_erode_by_travel_reaches_as_far_as_the_fastest_item_between_covers_in_the_span():
    # A window of span T covers at most T times the highest speed cap on its way: a slow item
    # between two fast ones is reached from both; an item behind slow ones only nearby.
    lo = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    hi = lo + 1.0
    value = np.array([9.0, 8.0, 1.0, 7.0, 6.0])
    speed = np.array([4.0, 4.0, 1.0, 0.5, 0.5])  # [m/s]
    span = 0.5  # [s]
    none = np.zeros(5)
    out = erode(lo, hi, value, none, np.zeros(5, dtype=np.int64), speed, span)
    # Items 0, 1 reach item 2 through speed 4 (gaps 1 and 0 <= 2); item 3 touches it; item 4
    # (gap 1) sees only speeds 1 and 0.5 on the way: 0.5 m, out of reach.
    np.testing.assert_array_equal(out, [1.0, 1.0, 1.0, 1.0, 6.0])


def test_box_filter_of_a_trapezoid_is_the_s_curve_in_closed_form():
    # Raw: from rest at A = 2 m/s^2 for 0.1 s, then 0.2 m/s. Filtered over T: the S-curve
    # ramp of jerk A / T = 40 m/s^3: s = J t^3 / 6 for t < T.
    A, t_up = 2.0, 0.1
    period = 1e-3
    times = np.arange(0, 301) * period
    pieces = dict(
        kind=np.array([BODY]), t0=np.array([0.0]), dur=np.array([0.3]), s0=np.array([0.0]),
        v0=np.array([0.0]), vp=np.array([A * t_up]), A=np.array([A]),
        t_up=np.array([t_up]), t_cruise=np.array([0.2]),
    )  # fmt: skip
    s, sd, F, F_lo, _, F_end, F_end_lo = raw_samples(times, **pieces, F0=0.0, F0_lo=0.0)
    n = int(round(T / period))
    before = -np.arange(n, 0, -1) * period
    history = np.column_stack((0 * before, 0 * before, 0 * before, before, 0 * before))
    smooth = box_filter(history, np.column_stack((s, sd, F, times, F_lo)), T)
    J = A / T
    early = times < T
    np.testing.assert_allclose(smooth[early, 0], J * times[early] ** 3 / 6, rtol=1e-9, atol=1e-16)
    np.testing.assert_allclose(smooth[early, 1], J * times[early] ** 2 / 2, rtol=1e-9, atol=1e-16)
    np.testing.assert_allclose(smooth[early, 2], J * times[early], rtol=1e-9, atol=1e-14)
    # At cruise the filtered plan runs T / 2 behind the raw one, at the same speed.
    late = times > t_up + T + 1e-9
    np.testing.assert_allclose(smooth[late, 1], A * t_up, rtol=1e-12)
    np.testing.assert_allclose(smooth[late, 0], s[late] - A * t_up * T / 2, rtol=1e-12)
    assert F_end + F_end_lo == pytest.approx(
        A * t_up**3 / 6 + (A * t_up**2 / 2) * 0.2 + A * t_up * 0.02
    )


def test_box_filter_keeps_its_precision_late_in_a_long_program():
    # The same trapezoid 170 s into a program whose integral of s has grown to 500 m s: the
    # window's integral (F(t) - F(t - T)) is a few mm s, so F in one double would leave
    # eps 500 / T = 2e-12 m in s_f (the samples' third differences multiply it by 8 / period^3:
    # 1.8e-2 m/s^3). Carried as two doubles, s_f is the closed form to 1e-15 m.
    A, t_up, t_start, F0 = 2.0, 0.1, 170.0, 500.0 + 1.0 / 3.0
    period = 1e-3
    times = t_start + np.arange(0, 301) * period
    pieces = dict(
        kind=np.array([BODY]), t0=np.array([t_start]), dur=np.array([0.3]),
        s0=np.array([0.0]), v0=np.array([0.0]), vp=np.array([A * t_up]), A=np.array([A]),
        t_up=np.array([t_up]), t_cruise=np.array([0.2]),
    )  # fmt: skip
    s, sd, F, F_lo, _, _, _ = raw_samples(times, **pieces, F0=F0, F0_lo=0.0)
    n = int(round(T / period))
    before = t_start - np.arange(n, 0, -1) * period
    # at rest at s = 0 before: F stays F0 there
    history = np.column_stack((0 * before, 0 * before, 0 * before + F0, before, 0 * before))
    smooth = box_filter(history, np.column_stack((s, sd, F, times, F_lo)), T)
    J = A / T
    tau = times - t_start
    early = tau < T
    np.testing.assert_allclose(smooth[early, 0], J * tau[early] ** 3 / 6, rtol=1e-9, atol=1e-15)
    # what F's high part alone (one double) gives: off by far more than 1e-15
    joined = np.concatenate((history[:, 2], F))
    single = (joined[n:] - joined[:-n]) / T
    assert np.max(np.abs(single[early] - J * tau[early] ** 3 / 6)) > 1e-13
