"""Controller configuration: loading, structure rules and error messages naming file and field."""

import copy

import numpy as np
import pytest

from feed_twin.control import cascade as cc
from feed_twin.control import config as ccfg
from feed_twin.control import layout as lay
from feed_twin.core.config import ConfigError

SOURCE = "config/test.yaml"
PMSM = {
    "base_period_s": 62.5e-6,
    "mode": "position",
    "nc_period_s": 1.0e-3,
    "drive": {"lead_m": 0.01, "J_total_kg_m2": 0.005, "K_t": 1.8, "effort_limit": 40.0},
    "position": {
        "period_s": 250e-6,
        "Kv_1_s": 50.0,
        "feedback": "linear_scale",
        "velocity_ff": 1.0,
        "following_error_limit_m": 2e-3,
    },
    "velocity": {
        "period_s": 125e-6,
        "Kp": 500.0,
        "Ti_s": 4e-3,
        "estimator": {"fir_taps": [0.5, 0.5], "lowpass_hz": 1500.0},
        "notch": {"frequency_hz": 800.0, "bandwidth_hz": 200.0, "depth": 0.05},
    },
    "current": {
        "period_s": 62.5e-6,
        "pole_pairs": 4,
        "R_s_ohm": 0.3,
        "L_d_H": 3e-3,
        "L_q_H": 3e-3,
        "psi_pm_Vs": 0.3,
        "Kp_d_V_A": 16.0,
        "Ti_d_s": 0.01,
        "Kp_q_V_A": 16.0,
        "Ti_q_s": 0.01,
    },
}


def _load(mapping):
    return ccfg.load_controller_config(mapping, SOURCE)


def _with(path: str, value):
    data = copy.deepcopy(PMSM)
    *parents, leaf = path.split(".")
    node = data
    for p in parents:
        node = node[p]
    node[leaf] = value
    return data


def test_machine_tool_config_flattens_to_named_slots():
    cascade = lay.build_cascade(_load(PMSM))
    p = dict(zip(cascade.param_names, cascade.params, strict=True))
    assert cascade.base_period_s == 62.5e-6
    assert (p["nc_div"], p["pos_div"], p["vel_div"], p["cur_div"]) == (16, 4, 2, 1)
    assert p["vel_Ki_T"] == pytest.approx(500.0 * 125e-6 / 4e-3)
    assert p["Ki_T_q"] == pytest.approx(16.0 * 62.5e-6 / 0.01)
    assert p["feedback_scale"] == 1.0 and p["fe_limit_m"] == 2e-3
    assert (p["fir_tap_0"], p["fir_tap_1"]) == (0.5, 0.5)
    assert len(cascade.initial_state()) == len(cascade.state_names)
    assert not cascade.params.flags.writeable
    # acceleration feed-forward is off unless configured; on, it is J*(2 pi/lead)/K_t per m/s^2
    assert p["acc_ff_gain"] == 0.0
    on = lay.build_cascade(_load(_with("position.acceleration_ff", 1.0)))
    gain = dict(zip(on.param_names, on.params, strict=True))["acc_ff_gain"]
    assert gain == pytest.approx(0.005 * 2 * np.pi / 0.01 / 1.8)


def test_flag_slots_hold_their_named_codes():
    p = dict(zip(lay.PARAM_NAMES, lay.build_cascade(_load(PMSM)).params, strict=False))
    assert p["feedback_scale"] == lay.FEEDBACK_SCALE  # linear_scale
    assert p["computation_delay"] == lay.DELAY_ONE_SAMPLE
    assert p["has_position"] == p["has_velocity"] == p["has_current"] == lay.LOOP_PRESENT
    off = lay.build_cascade(_load(_with("computation_delay", False)))
    assert off.params[lay.P_COMPUTATION_DELAY] == lay.DELAY_NONE
    cs = lay.build_cascade(_load(PMSM)).initial_state()
    assert cs[lay.S_INITIALISED] == lay.PENDING
    lay.disable(cs)
    assert cs[lay.S_ENABLE_CMD] == lay.STAGE_OFF
    lay.enable(cs)
    assert cs[lay.S_ENABLE_CMD] == lay.STAGE_ON


def test_each_slot_constant_is_the_position_of_its_name():
    assert lay.PARAM_NAMES[lay.P_KV] == "Kv_1_s"
    assert lay.PARAM_NAMES[lay.P_BQ_NOTCH : lay.P_BQ_NOTCH + 5] == tuple(
        f"bq_notch_{c}" for c in ("b0", "b1", "b2", "a1", "a2")
    )
    assert lay.STATE_NAMES[lay.S_PARK_ANCHOR + 2] == "park_anchor_sin"
    assert lay.STATE_NAMES[lay.S_DUTY_NEXT + 3 : lay.S_DUTY + 3] == ("duty_a", "duty_b", "duty_c")


@pytest.mark.parametrize(
    ("names", "name", "following", "message"),
    [
        (("a", "b"), "c", (), "slot 'c': declared 0 times, not once"),
        (("a", "b", "a"), "a", (), "slot 'a': declared 2 times, not once"),
        (("a", "c", "b"), "a", ("b",), r"slot 'a': expected \('b',\) after it, found \('c',\)"),
    ],
)
def test_slot_lookup_errors(names, name, following, message):
    with pytest.raises(ValueError, match=message):
        lay._slot(names, name, *following)


def test_with_mode_switches_the_boundary():
    cascade = lay.build_cascade(_load(PMSM))
    torque = lay.with_mode(cascade, "torque")
    assert torque.params[lay.P_MODE] == cc.MODE_TORQUE
    assert torque.params[lay.P_KV] == cascade.params[lay.P_KV]


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (
            "velocity.period_s",
            100e-6,
            "config/test.yaml: controller.velocity.period_s = 0.0001: must be an integer "
            "multiple of base_period_s = 6.25e-05",
        ),
        (
            "nc_period_s",
            1.03e-3,
            "config/test.yaml: controller.nc_period_s = 0.00103: must be an integer multiple of "
            "base_period_s = 6.25e-05",
        ),
        ("velocity.Kp", -3.0, "config/test.yaml: controller.velocity.Kp = -3.0: must be >= 0"),
        (
            "position.Kv_1_s",
            -1.0,
            "config/test.yaml: controller.position.Kv_1_s = -1.0: must be >= 0",
        ),
        (
            "current.Ti_q_s",
            0.0,
            "config/test.yaml: controller.current.Ti_q_s = 0.0: must be > 0",
        ),
        (
            "position.velocity_ff",
            1.5,
            "config/test.yaml: controller.position.velocity_ff = 1.5: must lie in [0.0, 1.0]",
        ),
        (
            "drive.lead_m",
            0.0,
            "config/test.yaml: controller.drive.lead_m = 0.0: must be > 0",
        ),
        (
            "velocity.estimator.fir_taps",
            [0.5, 0.4],
            "config/test.yaml: controller.velocity.estimator.fir_taps = [0.5, 0.4]: must sum to 1",
        ),
        (
            "position.feedback",
            "tachometer",
            "config/test.yaml: controller.position.feedback = 'tachometer': must be one of "
            "'motor_encoder', 'linear_scale'",
        ),
        (
            "mode",
            "homing",
            "config/test.yaml: controller.mode = 'homing': must be one of 'position', "
            "'velocity', 'torque'",
        ),
        (
            "position.feed_forward_rate",
            "current",
            "config/test.yaml: controller.position.feed_forward_rate = 'current': must be one of "
            "'position', 'velocity'",
        ),
        (
            "position.interpolation",
            "spline",
            "config/test.yaml: controller.position.interpolation = 'spline': must be one of "
            "'hold', 'linear', 'extrapolate', 'cubic'",
        ),
        (
            "velocity.notch.frequency_hz",
            5000.0,
            "config/test.yaml: controller.velocity.notch.frequency_hz = 5000.0: must lie below "
            "the velocity loop's Nyquist frequency 4000.0 Hz",
        ),
        (
            "velocity.estimator.lowpass_hz",
            4000.0,
            "config/test.yaml: controller.velocity.estimator.lowpass_hz = 4000.0: must lie below "
            "the velocity loop's Nyquist frequency 4000.0 Hz",
        ),
        (
            "position.period_s",
            3.75e-4,
            "config/test.yaml: controller.nc_period_s = 0.001: must be an integer multiple of "
            "position.period_s = 0.000375",
        ),
        (
            "current.pole_pairs",
            2.5,
            "config/test.yaml: controller.current.pole_pairs = 2.5: expected a whole number",
        ),
    ],
)
def test_bad_values_name_file_field_and_value(path, value, message):
    with pytest.raises(ConfigError) as err:
        _load(_with(path, value))
    assert str(err.value).startswith(message)


def test_unknown_key_is_rejected_with_the_allowed_ones():
    with pytest.raises(ConfigError) as err:
        _load(_with("velocity.Kd", 3.0))
    assert str(err.value).startswith(
        "config/test.yaml: controller.velocity: unknown key(s) Kd; allowed: period_s, Kp, Ti_s"
    )


def test_missing_required_field_is_named():
    data = copy.deepcopy(PMSM)
    del data["drive"]["K_t"]
    with pytest.raises(ConfigError, match=r"controller\.drive: missing required field\(s\) K_t"):
        _load(data)


def test_mode_needs_its_loops():
    data = copy.deepcopy(PMSM)
    del data["position"]
    with pytest.raises(ConfigError) as err:
        _load(data)
    assert str(err.value) == (
        "config/test.yaml: controller.mode = 'position': needs a position section"
    )
    data["mode"] = "velocity"
    del data["velocity"]
    with pytest.raises(ConfigError, match="mode = 'velocity': needs a velocity section"):
        _load(data)


def test_position_loop_needs_a_velocity_loop():
    data = copy.deepcopy(PMSM)
    del data["velocity"]
    data["mode"] = "torque"
    with pytest.raises(ConfigError) as err:
        _load(data)
    assert str(err.value) == (
        "config/test.yaml: controller.position: a position loop needs a velocity loop under it"
    )


def test_fault_reason_texts():
    assert lay.fault_reason(1.0) == "following error limit exceeded"
    with pytest.raises(ValueError, match=r"fault code = 9.0: unknown; known: \[0, 1, 2, 3\]"):
        lay.fault_reason(9.0)


def test_source_digest_names_the_kernel_sources():
    digest = cc.source_digest()
    assert len(digest) == 20 and int(digest, 16) >= 0
    assert digest == cc.source_digest()


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: ccfg.VelocityEstimatorConfig(fir_taps=(1.0 / 17,) * 17),
            "fir_taps = [",
        ),
        (
            lambda: ccfg.CurrentLoopConfig(**{**PMSM["current"], "pole_pairs": 2.0}),
            "pole_pairs = 2.0: must be a whole number",
        ),
        (
            lambda: ccfg.PositionLoopConfig(
                period_s=1e-3,
                Kv_1_s=10.0,
                feedback="tacho",  # pyright: ignore[reportArgumentType]  the bad value under test
            ),
            "feedback = 'tacho': must be one of 'motor_encoder', 'linear_scale'",
        ),
        (
            lambda: ccfg.PositionLoopConfig(
                period_s=1e-3,
                Kv_1_s=10.0,
                feedback="linear_scale",
                feed_forward_rate="nc",  # pyright: ignore[reportArgumentType]  the bad value under test
            ),
            "feed_forward_rate = 'nc': must be one of 'position', 'velocity'",
        ),
        (
            lambda: ccfg.NotchConfig(frequency_hz=100.0, bandwidth_hz=10.0, depth=1.5),
            "depth = 1.5: must lie in [0.0, 1.0]",
        ),
    ],
)
def test_direct_construction_errors(build, message):
    with pytest.raises(ValueError) as err:
        build()
    assert str(err.value).startswith(message)


def test_with_mode_rejects_an_unknown_mode():
    cascade = lay.build_cascade(_load(PMSM))
    with pytest.raises(ValueError) as err:
        lay.with_mode(cascade, "homing")
    assert str(err.value) == "mode = 'homing': must be one of 'position', 'velocity', 'torque'"


def test_too_many_fir_taps_message():
    with pytest.raises(ValueError) as err:
        ccfg.VelocityEstimatorConfig(fir_taps=(1.0 / 17,) * 17)
    assert str(err.value).endswith(": must have 1 to 16 entries")
