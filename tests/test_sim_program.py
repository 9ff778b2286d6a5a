"""simulate_program, the seam from a G-code program to recorded signals, against physics.

A P position loop around a fast velocity loop follows a ramp with the steady error v/Kv
(without feed-forward); the NC's linear interpolation between its samples adds up to one NC
period of lag, v * T_nc. With velocity and acceleration feed-forward only that lag is left.
At the end of the settle the table stands at the programmed target.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from feed_twin.core import signals
from feed_twin.core.config import ConfigError, load_yaml
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.program import nc_reference, set_nc_reference, simulate_program

ROOT = Path(__file__).resolve().parents[1]
FEED_M_S = 0.01  # F600 mm/min
TARGET_M = 0.42  # G54 X20 from the NC start X = 0.4 m
PROGRAM = "G21 G90 G54 G64\nG1 X20 F600\nM30\n"


def axis(feed_forward: bool):
    data = copy.deepcopy(load_yaml(ROOT / "config/axis_default.yaml"))
    position = data["controller"]["position"]
    position["velocity_ff"] = position["acceleration_ff"] = 1.0 if feed_forward else 0.0
    return load_axis_config(data, source="test axis"), float(position["Kv_1_s"])


@pytest.fixture(scope="module")
def program(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("prog") / "ramp.ngc"
    path.write_text(PROGRAM)
    return path


@pytest.fixture(scope="module")
def without_ff(program):
    config, Kv = axis(feed_forward=False)
    return simulate_program(config, program, settle_s=0.6), Kv


def steady(run) -> np.ndarray:
    """Samples of the constant-feed part (well after the S-curve's ramp, before its stop)."""
    v = run.command_vel[:, run.axes.index("X")]
    return np.abs(v - FEED_M_S) < 1e-12


def test_steady_following_error_is_v_over_kv_without_feed_forward(without_ff) -> None:
    run, Kv = without_ff
    cruise = steady(run)
    assert cruise.sum() > 1000  # 1 s and more at the feed
    fe = run.following_error("X")[cruise]
    settled = fe[len(fe) // 2 :]  # the loop's transient (1/Kv = 33 ms) long gone
    expected = FEED_M_S / Kv  # 333 um
    lag = FEED_M_S * 1e-3  # one NC period of interpolation lag, 10 um
    assert expected - 1e-6 <= settled.min() and settled.max() <= expected + lag + 1e-6
    assert np.ptp(settled) < 1e-6  # a steady error, not a drift
    # the drive's own following error (against its interpolated setpoint) is v/Kv itself
    drive_fe = run.signal("X", "out.following_error_m")[cruise][len(fe) // 2 :]
    assert drive_fe.mean() == pytest.approx(expected, rel=0.01)


def test_the_axis_reaches_the_target_and_stops(without_ff) -> None:
    run, _ = without_ff
    assert run.commanded("X")[-1] == pytest.approx(TARGET_M, abs=1e-12)
    assert run.position("X")[-1] == pytest.approx(TARGET_M, abs=2e-6)
    assert abs(run.signal("X", "table.v")[-1]) < 1e-4
    # axes without a plant are their command
    np.testing.assert_array_equal(run.position("Y"), run.commanded("Y"))
    assert run.simulated == ("X",)


def test_feed_forward_leaves_only_the_interpolation_lag(program, without_ff) -> None:
    config, _ = axis(feed_forward=True)
    run = simulate_program(config, program, settle_s=0.1)
    cruise = steady(run)
    fe = run.following_error("X")[cruise]
    fe = fe[len(fe) // 2 :]
    lag = FEED_M_S * 1e-3  # the fine interpolator runs one NC period behind: 10 um
    assert 0.5 * lag < fe.min() and fe.max() < lag + 1e-7
    # against its own (interpolated) setpoint the drive has next to no error left
    drive_fe = run.signal("X", "out.following_error_m")[cruise]
    assert np.abs(drive_fe[len(drive_fe) // 2 :]).max() < 1e-7
    plain = without_ff[0].following_error("X")[steady(without_ff[0])]
    assert fe.max() < 0.05 * plain[len(plain) // 2 :].min()


def test_nc_reference_holds_each_sample_for_its_ticks() -> None:
    x, v, a = np.array([1.0, 2.0]), np.array([3.0, 4.0]), np.array([5.0, 6.0])
    ref = nc_reference(x, v, a, 3)
    assert ref.shape == (6, signals.REF_SIZE)
    np.testing.assert_array_equal(ref[:, signals.REF_POS_M], [1, 1, 1, 2, 2, 2])
    np.testing.assert_array_equal(ref[:, signals.REF_VEL_M_S], [3, 3, 3, 4, 4, 4])
    np.testing.assert_array_equal(ref[:, signals.REF_ACC_M_S2], [5, 5, 5, 6, 6, 6])
    assert np.count_nonzero(ref) == 18  # nothing else is set
    row = np.full(signals.REF_SIZE, 7.0)
    set_nc_reference(row, 1.0, 2.0, 3.0)
    assert row[signals.REF_POS_M] == 1.0 and row[signals.REF_ACC_M_S2] == 3.0
    assert row[signals.REF_EFFORT_ADD] == 7.0  # the other slots are left as they were


def test_an_axis_without_nc_section_is_refused(program) -> None:
    config = load_axis_config(ROOT / "config/emps.yaml")
    with pytest.raises(ConfigError, match=r"emps\.yaml: simulating a program needs an nc:"):
        simulate_program(config, program)


def test_unknown_axis_and_signal_are_named(without_ff) -> None:
    run, _ = without_ff
    with pytest.raises(KeyError, match=r"axis 'A': not an NC axis \(axes: X, Y, Z\)"):
        run.following_error("A")
    with pytest.raises(KeyError, match=r"axis 'Y': not simulated \(simulated: X\)"):
        run.signal("Y", "table.s")
    with pytest.raises(KeyError, match=r"axis X: signal 'motor.nope' was not recorded"):
        run.signal("X", "motor.nope")
