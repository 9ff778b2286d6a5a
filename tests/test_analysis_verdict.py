"""The verdict (analysis.verdict): never "no significant missing effect" while a residual far
above the noise remains; the residual's size and its signature (when, where, what it follows)."""

from __future__ import annotations

import numpy as np

from feed_twin.analysis.verdict import FAR_ABOVE_NOISE, Leftover, signature, verdict


def _motion(n: int = 4000):
    t = np.linspace(0.0, 8.0, n)
    x = 0.05 * (1.0 - np.cos(2 * np.pi * t / 4.0))
    v = np.gradient(x, t)
    a = np.gradient(v, t)
    return t, x, v, a


def _left(ratio: float, channel: str = "position", sig: str = "it follows the speed") -> Leftover:
    return Leftover(channel=channel, unit="m", rms=ratio * 1e-8, noise_ratio=ratio, signature=sig)


def test_a_delayed_position_follows_the_speed():
    t, x, v, a = _motion()
    words = signature(0.002 * v, t, x, v, a)  # a 2 ms delay of the recorded position
    assert "it follows the speed (correlation +1.00)" in words, words


def test_a_residual_that_grows_over_the_record_says_so_and_when():
    t, x, v, a = _motion()
    r = np.sign(v) * (1.0 + 3.0 * t / t[-1])  # a friction that grows 4x over the record
    words = signature(r, t, x, v, a)
    assert words.startswith("largest at t = 6.4..8 s, growing over the record"), words


def test_a_residual_on_the_accelerations_is_placed_there():
    t, x, v, a = _motion()
    words = signature(a**3, t, x, v, a)
    share = float(words.split("; ")[1].split(" %")[0])
    assert "while accelerating" in words and share > 90.0, words


def test_no_significant_missing_effect_only_near_the_noise():
    quiet = verdict([], [], [_left(3.0), _left(1.2, "effort")])
    assert quiet.startswith("no significant missing effect"), quiet
    loud = verdict([], [], [_left(3.35e4), _left(1.2, "effort")])
    assert loud == (
        "no effect of the library is missing, but a residual far above the noise remains that "
        "no effect of the library explains (position residual RMS 0.000335 m = 3.35e+04 x its "
        "sample noise: it follows the speed)"
    )


def test_found_effects_with_a_large_residual_left_say_both():
    text = verdict(["coulomb_friction"], [], [_left(2 * FAR_ABOVE_NOISE)])
    assert text.startswith(
        "the nominal model misses coulomb_friction; with them the gap shrinks as shown, but a "
        "residual far above the noise remains"
    ), text
    assert verdict(["coulomb_friction"], [], [_left(2.0)]) == (
        "the nominal model misses coulomb_friction; with them the gap shrinks as shown"
    )
    unfitted = verdict([], ["cogging_torque"], [_left(50.0)])
    assert unfitted.startswith(
        "the residual carries the signature of cogging_torque, which could not be fitted; a "
        "residual far above"
    ), unfitted
