"""The controller's flat vectors: parameter and state layouts, and building them from a config.

`build_cascade(config)` flattens a ControllerConfig (feed_twin.control.config) into the read-only
parameter vector that the compiled tick (feed_twin.control.cascade) reads by the P_* slots; the
state vector it updates has the S_* slots. The drive commands (`enable`, `disable`,
`clear_fault`) write a state vector the way a CiA 402 controlword does.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from feed_twin.control.blocks import (
    BIQUAD_IDENTITY,
    lowpass1_alpha,
    lowpass2_coefficients,
    notch_coefficients,
)
from feed_twin.control.config import (
    INTERPOLATION_CODES,
    MODE_CODES,
    TWO_PI,
    ControllerConfig,
)
from feed_twin.core import signals as sig

# Flat layouts. Each vector's slots are declared once, as names in order; every P_*/S_* constant
# is looked up by its name (`_slot`), so a constant cannot point at another slot than the one it
# names, and an unknown name fails at import. numba folds these module integers into the kernels.

PARAM_NAMES = (
    "base_period_s",
    "mode",  # a config.MODE_* code
    "computation_delay",  # DELAY_NONE or DELAY_ONE_SAMPLE
    "nc_div",
    "lead_m",
    "effort_limit",
    "has_position",  # LOOP_ABSENT or LOOP_PRESENT, as has_velocity and has_current
    "pos_div",
    "Kv_1_s",
    "velocity_ff",
    "acc_ff_gain",
    "feedback_scale",  # FEEDBACK_ENCODER or FEEDBACK_SCALE
    "interpolation",  # a config.INTERP_* code
    "ff_rate",  # FF_AT_POSITION or FF_AT_VELOCITY: where the feed-forwards are added
    "fe_limit_m",
    "v_limit_m_s",
    "has_velocity",
    "vel_div",
    "vel_period_s",
    "vel_Kp",
    "vel_Ki_T",
    "vel_lowpass_alpha",
    "fir_n",
    *(f"bq_lp_{c}" for c in ("b0", "b1", "b2", "a1", "a2")),
    *(f"bq_notch_{c}" for c in ("b0", "b1", "b2", "a1", "a2")),
    "has_current",
    "cur_div",
    "cur_period_s",
    "pole_pairs",
    "L_d_H",
    "L_q_H",
    "psi_pm_Vs",
    "Kp_d",
    "Ki_T_d",
    "Kp_q",
    "Ki_T_q",
    "decoupling",  # a gain, 0 or 1
    "back_emf_ff",  # a gain, 0 or 1
    "voltage_margin",
    "angle_advance_periods",
    "encoder_offset_rad",
    "i_trip_A",
    "dead_time_comp_V",
    "dead_time_comp_band_A",
    "m_per_rad",
    "rad_per_m",
    "vel_rate_1_s",
    "nc_div_inv",
)

STATE_NAMES = (
    "initialised",  # PENDING or STARTED
    "enable_cmd",  # STAGE_OFF or STAGE_ON
    "fault",  # a signals.FAULT_* code
    "nc_tick",
    *(f"nc_prev_{q}" for q in ("pos_m", "vel_m_s", "acc_m_s2")),
    *(f"nc_{q}" for q in ("pos_m", "vel_m_s", "acc_m_s2")),
    "pos_ref_m",
    "following_error_m",
    "vel_cmd_m_s",
    "effort_ff",
    "vel_est_m_s",
    "enc_pos_prev_m",
    "vel_int",
    "effort_cmd",
    "bq_lp_s1",
    "bq_lp_s2",
    "bq_notch_s1",
    "bq_notch_s2",
    "i_d_int",
    "i_q_int",
    "u_d_ref_V",
    "u_q_ref_V",
    *(f"duty_next_{x}" for x in "abc"),
    *(f"duty_{x}" for x in "abc"),
    "effort_next",
    "effort_out",
    # the last electrical angle whose sine and cosine were evaluated in full, and that pair
    # (feed_twin.core.trig.sincos_anchored)
    "park_anchor_rad",
    "park_anchor_cos",
    "park_anchor_sin",
)


def _slot(names: tuple[str, ...], name: str, *following: str) -> int:
    """Position of `name` in `names`; `following` names the slots a block reads after it."""
    if names.count(name) != 1:
        raise ValueError(f"slot {name!r}: declared {names.count(name)} times, not once")
    i = names.index(name)
    found = names[i + 1 : i + 1 + len(following)]
    if found != following:
        raise ValueError(f"slot {name!r}: expected {following} after it, found {found}")
    return i


_BQ = ("b1", "b2", "a1", "a2")

P_BASE_PERIOD = _slot(PARAM_NAMES, "base_period_s")
P_MODE = _slot(PARAM_NAMES, "mode")
P_COMPUTATION_DELAY = _slot(PARAM_NAMES, "computation_delay")
P_NC_DIV = _slot(PARAM_NAMES, "nc_div")
P_LEAD = _slot(PARAM_NAMES, "lead_m")
P_EFFORT_LIMIT = _slot(PARAM_NAMES, "effort_limit")
P_HAS_POSITION = _slot(PARAM_NAMES, "has_position")
P_POS_DIV = _slot(PARAM_NAMES, "pos_div")
P_KV = _slot(PARAM_NAMES, "Kv_1_s")
P_VFF = _slot(PARAM_NAMES, "velocity_ff")
P_ACC_FF_GAIN = _slot(PARAM_NAMES, "acc_ff_gain")
P_FEEDBACK_SCALE = _slot(PARAM_NAMES, "feedback_scale")
P_INTERPOLATION = _slot(PARAM_NAMES, "interpolation")
P_FF_RATE = _slot(PARAM_NAMES, "ff_rate")
P_FE_LIMIT = _slot(PARAM_NAMES, "fe_limit_m")
P_V_LIMIT = _slot(PARAM_NAMES, "v_limit_m_s")
P_HAS_VELOCITY = _slot(PARAM_NAMES, "has_velocity")
P_VEL_DIV = _slot(PARAM_NAMES, "vel_div")
P_VEL_PERIOD = _slot(PARAM_NAMES, "vel_period_s")
P_VEL_KP = _slot(PARAM_NAMES, "vel_Kp")
P_VEL_KI_T = _slot(PARAM_NAMES, "vel_Ki_T")
P_VEL_LP_ALPHA = _slot(PARAM_NAMES, "vel_lowpass_alpha")
P_FIR_N = _slot(PARAM_NAMES, "fir_n")
P_BQ_LP = _slot(PARAM_NAMES, "bq_lp_b0", *(f"bq_lp_{c}" for c in _BQ))  # b0 b1 b2 a1 a2
P_BQ_NOTCH = _slot(PARAM_NAMES, "bq_notch_b0", *(f"bq_notch_{c}" for c in _BQ))
P_HAS_CURRENT = _slot(PARAM_NAMES, "has_current")
P_CUR_DIV = _slot(PARAM_NAMES, "cur_div")
P_CUR_PERIOD = _slot(PARAM_NAMES, "cur_period_s")
P_POLE_PAIRS = _slot(PARAM_NAMES, "pole_pairs")
P_L_D = _slot(PARAM_NAMES, "L_d_H")
P_L_Q = _slot(PARAM_NAMES, "L_q_H")
P_PSI_PM = _slot(PARAM_NAMES, "psi_pm_Vs")
P_KP_D = _slot(PARAM_NAMES, "Kp_d")
P_KI_T_D = _slot(PARAM_NAMES, "Ki_T_d")
P_KP_Q = _slot(PARAM_NAMES, "Kp_q")
P_KI_T_Q = _slot(PARAM_NAMES, "Ki_T_q")
P_DECOUPLING = _slot(PARAM_NAMES, "decoupling")
P_BACK_EMF_FF = _slot(PARAM_NAMES, "back_emf_ff")
P_VOLTAGE_MARGIN = _slot(PARAM_NAMES, "voltage_margin")
P_ANGLE_ADVANCE = _slot(PARAM_NAMES, "angle_advance_periods")
P_ENCODER_OFFSET = _slot(PARAM_NAMES, "encoder_offset_rad")
P_I_TRIP = _slot(PARAM_NAMES, "i_trip_A")
P_DEAD_TIME_COMP = _slot(PARAM_NAMES, "dead_time_comp_V")
P_DEAD_TIME_BAND = _slot(PARAM_NAMES, "dead_time_comp_band_A")
P_M_PER_RAD = _slot(PARAM_NAMES, "m_per_rad")
P_RAD_PER_M = _slot(PARAM_NAMES, "rad_per_m")
P_VEL_RATE = _slot(PARAM_NAMES, "vel_rate_1_s")
P_NC_DIV_INV = _slot(PARAM_NAMES, "nc_div_inv")
P_FIR_TAPS = len(PARAM_NAMES)  # the FIR taps follow the named slots

_XVA = ("vel_m_s", "acc_m_s2")

S_INITIALISED = _slot(STATE_NAMES, "initialised")
S_ENABLE_CMD = _slot(STATE_NAMES, "enable_cmd")
S_FAULT = _slot(STATE_NAMES, "fault")
S_NC_TICK = _slot(STATE_NAMES, "nc_tick")
S_NC_PREV_POS = _slot(STATE_NAMES, "nc_prev_pos_m", *(f"nc_prev_{q}" for q in _XVA))  # x, v, a
S_NC_POS = _slot(STATE_NAMES, "nc_pos_m", *(f"nc_{q}" for q in _XVA))  # x, v, a
S_POS_REF = _slot(STATE_NAMES, "pos_ref_m")
S_FOLLOWING_ERROR = _slot(STATE_NAMES, "following_error_m")
S_VEL_CMD = _slot(STATE_NAMES, "vel_cmd_m_s")
S_EFFORT_FF = _slot(STATE_NAMES, "effort_ff")
S_VEL_EST = _slot(STATE_NAMES, "vel_est_m_s")
S_ENC_POS_PREV = _slot(STATE_NAMES, "enc_pos_prev_m")
S_VEL_INT = _slot(STATE_NAMES, "vel_int")
S_EFFORT_CMD = _slot(STATE_NAMES, "effort_cmd")
S_BQ_LP = _slot(STATE_NAMES, "bq_lp_s1", "bq_lp_s2")
S_BQ_NOTCH = _slot(STATE_NAMES, "bq_notch_s1", "bq_notch_s2")
S_I_D_INT = _slot(STATE_NAMES, "i_d_int")
S_I_Q_INT = _slot(STATE_NAMES, "i_q_int")
S_U_D_REF = _slot(STATE_NAMES, "u_d_ref_V")
S_U_Q_REF = _slot(STATE_NAMES, "u_q_ref_V")
S_DUTY_NEXT = _slot(STATE_NAMES, "duty_next_a", "duty_next_b", "duty_next_c")
S_DUTY = _slot(STATE_NAMES, "duty_a", "duty_b", "duty_c")
S_EFFORT_NEXT = _slot(STATE_NAMES, "effort_next")
S_EFFORT_OUT = _slot(STATE_NAMES, "effort_out")
S_PARK_ANCHOR = _slot(STATE_NAMES, "park_anchor_rad", "park_anchor_cos", "park_anchor_sin")
S_FIR_HIST = len(STATE_NAMES)  # the FIR difference history follows the named slots

# Values of the integer-valued slots: exact in the float64 vectors, compared for equality.
LOOP_ABSENT, LOOP_PRESENT = 0, 1  # has_position, has_velocity, has_current
FEEDBACK_ENCODER, FEEDBACK_SCALE = 0, 1  # feedback_scale: semi-closed or closed position loop
DELAY_NONE, DELAY_ONE_SAMPLE = 0, 1  # computation_delay
FF_AT_POSITION, FF_AT_VELOCITY = 0, 1  # ff_rate: the position loop's rate or the velocity loop's
PENDING, STARTED = 0, 1  # initialised: the first tick latches the setpoint and the encoder
STAGE_OFF, STAGE_ON = 0, 1  # enable_cmd: the power stage as requested (CiA 402 controlword)

# The cascade's structure: its mode, which loops exist and at what rates, the feedback source,
# the interpolation and the feed-forward's rate, the FIR's length and the computation delay. The
# engine compiles these slots into its kernel as constants (one kernel per structure, as a
# Modelica tool evaluates structural parameters), so the tick has no branch on them; every other
# slot is read as the loop runs.
STRUCTURE_NAMES = (
    "base_period_s",
    "mode",
    "computation_delay",
    "nc_div",
    "nc_div_inv",
    "has_position",
    "pos_div",
    "feedback_scale",
    "interpolation",
    "ff_rate",
    "has_velocity",
    "vel_div",
    "fir_n",
    "has_current",
    "cur_div",
)
STRUCTURE_SLOTS = tuple(PARAM_NAMES.index(n) for n in STRUCTURE_NAMES)


@dataclass(frozen=True, kw_only=True)
class CompiledCascade:
    """A configuration flattened for `cascade_tick`: parameters, state layout and base period."""

    config: ControllerConfig
    params: np.ndarray  # float64, read-only, slots PARAM_NAMES then the FIR taps
    base_period_s: float  # [s]
    param_names: tuple[str, ...]
    state_names: tuple[str, ...]

    def initial_state(self) -> np.ndarray:
        """A fresh state vector: everything zero, drive enabled if configured so."""
        cs = np.zeros(len(self.state_names))
        cs[S_ENABLE_CMD] = STAGE_ON if self.config.enabled_at_start else STAGE_OFF
        cs[S_DUTY_NEXT : S_DUTY_NEXT + 3] = 0.5
        cs[S_DUTY : S_DUTY + 3] = 0.5
        cs[S_PARK_ANCHOR : S_PARK_ANCHOR + 3] = 0.0, 1.0, 0.0  # the angle 0 and its exact pair
        return cs

    def state_view(self, cs: np.ndarray) -> dict[str, float]:
        """Named copy of a state vector, for reports and debugging."""
        return {name: float(v) for name, v in zip(self.state_names, cs, strict=True)}


def build_cascade(config: ControllerConfig) -> CompiledCascade:
    """Flatten a ControllerConfig into the parameter vector read by `cascade_tick`."""
    base = config.base_period_s
    drive = config.drive
    p = np.zeros(P_FIR_TAPS)
    p[P_BASE_PERIOD] = base
    p[P_MODE] = MODE_CODES[config.mode]
    p[P_COMPUTATION_DELAY] = DELAY_ONE_SAMPLE if config.computation_delay else DELAY_NONE
    p[P_NC_DIV] = round(config.nc_period_s / base)
    p[P_LEAD] = drive.lead_m
    # reciprocals the tick would otherwise divide by: a division is 13 cycles on its path
    p[P_M_PER_RAD] = drive.lead_m / TWO_PI
    p[P_RAD_PER_M] = TWO_PI / drive.lead_m
    p[P_NC_DIV_INV] = 1.0 / p[P_NC_DIV]
    p[P_EFFORT_LIMIT] = drive.effort_limit
    p[P_V_LIMIT] = math.inf
    p[P_FE_LIMIT] = math.inf
    p[P_I_TRIP] = math.inf
    p[P_BQ_LP : P_BQ_LP + 5] = BIQUAD_IDENTITY
    p[P_BQ_NOTCH : P_BQ_NOTCH + 5] = BIQUAD_IDENTITY
    p[P_VEL_LP_ALPHA] = 1.0
    taps: tuple[float, ...] = (1.0,)
    pos = config.position
    if pos is not None:
        p[P_HAS_POSITION] = LOOP_PRESENT
        p[P_POS_DIV] = round(pos.period_s / base)
        p[P_KV] = pos.Kv_1_s
        p[P_VFF] = pos.velocity_ff
        # a [m/s^2] -> motor angular acceleration -> torque J*alpha -> effort torque/K_t
        p[P_ACC_FF_GAIN] = (
            pos.acceleration_ff * (TWO_PI / drive.lead_m) * (drive.J_total_kg_m2 / drive.K_t)
        )
        p[P_FEEDBACK_SCALE] = FEEDBACK_SCALE if pos.feedback == "linear_scale" else FEEDBACK_ENCODER
        p[P_INTERPOLATION] = INTERPOLATION_CODES[pos.interpolation]
        p[P_FF_RATE] = FF_AT_VELOCITY if pos.feed_forward_rate == "velocity" else FF_AT_POSITION
        if pos.following_error_limit_m is not None:
            p[P_FE_LIMIT] = pos.following_error_limit_m
        if pos.velocity_limit_m_s is not None:
            p[P_V_LIMIT] = pos.velocity_limit_m_s
    vel = config.velocity
    if vel is not None:
        T_v = vel.period_s
        p[P_HAS_VELOCITY] = LOOP_PRESENT
        p[P_VEL_DIV] = round(T_v / base)
        p[P_VEL_PERIOD] = T_v
        p[P_VEL_RATE] = 1.0 / T_v
        p[P_VEL_KP] = vel.Kp
        p[P_VEL_KI_T] = 0.0 if vel.Ti_s is None else vel.Kp * T_v / vel.Ti_s
        if vel.estimator.lowpass_hz is not None:
            p[P_VEL_LP_ALPHA] = lowpass1_alpha(vel.estimator.lowpass_hz, T_v)
        taps = vel.estimator.fir_taps
        if vel.setpoint_lowpass_hz is not None:
            p[P_BQ_LP : P_BQ_LP + 5] = lowpass2_coefficients(
                frequency_hz=vel.setpoint_lowpass_hz, period_s=T_v
            )
        if vel.notch is not None:
            p[P_BQ_NOTCH : P_BQ_NOTCH + 5] = notch_coefficients(
                frequency_hz=vel.notch.frequency_hz,
                bandwidth_hz=vel.notch.bandwidth_hz,
                depth=vel.notch.depth,
                period_s=T_v,
            )
    cur = config.current
    if cur is not None:
        T_i = cur.period_s
        p[P_HAS_CURRENT] = LOOP_PRESENT
        p[P_CUR_DIV] = round(T_i / base)
        p[P_CUR_PERIOD] = T_i
        p[P_POLE_PAIRS] = cur.pole_pairs
        p[P_L_D] = cur.L_d_H
        p[P_L_Q] = cur.L_q_H
        p[P_PSI_PM] = cur.psi_pm_Vs
        p[P_KP_D] = cur.Kp_d_V_A
        p[P_KI_T_D] = cur.Kp_d_V_A * T_i / cur.Ti_d_s
        p[P_KP_Q] = cur.Kp_q_V_A
        p[P_KI_T_Q] = cur.Kp_q_V_A * T_i / cur.Ti_q_s
        p[P_DECOUPLING] = float(cur.decoupling)
        p[P_BACK_EMF_FF] = float(cur.back_emf_ff)
        p[P_VOLTAGE_MARGIN] = cur.voltage_margin
        p[P_ANGLE_ADVANCE] = cur.angle_advance_periods
        p[P_ENCODER_OFFSET] = cur.encoder_offset_rad
        if cur.i_trip_A is not None:
            p[P_I_TRIP] = cur.i_trip_A
        p[P_DEAD_TIME_COMP] = cur.dead_time_comp_V
        p[P_DEAD_TIME_BAND] = cur.dead_time_comp_band_A
    p[P_FIR_N] = len(taps)
    params = np.concatenate([p, np.asarray(taps, dtype=np.float64)])
    params.setflags(write=False)
    fir_names = tuple(f"fir_diff_{i}" for i in range(len(taps)))
    tap_names = tuple(f"fir_tap_{i}" for i in range(len(taps)))
    return CompiledCascade(
        config=config,
        params=params,
        base_period_s=base,
        param_names=PARAM_NAMES + tap_names,
        state_names=STATE_NAMES + fir_names,
    )


def with_mode(cascade: CompiledCascade, mode: str) -> CompiledCascade:
    """The same controller at another CiA 402 boundary (validated like a loaded config)."""
    return build_cascade(dataclasses.replace(cascade.config, mode=mode))


def enable(cs: np.ndarray) -> None:
    """Request the power stage on (takes effect at the next tick unless a fault is latched)."""
    cs[S_ENABLE_CMD] = STAGE_ON


def disable(cs: np.ndarray) -> None:
    """Request the power stage off; integrators are cleared at the next tick."""
    cs[S_ENABLE_CMD] = STAGE_OFF


def clear_fault(cs: np.ndarray) -> None:
    """Acknowledge a latched fault (fault reset)."""
    cs[S_FAULT] = sig.FAULT_NONE


def fault_reason(code: float) -> str:
    """Text of a FAULT_* code as found in OUT_FAULT."""
    key = int(code)
    if key not in sig.FAULT_REASONS:
        raise ValueError(f"fault code = {code!r}: unknown; known: {sorted(sig.FAULT_REASONS)}")
    return sig.FAULT_REASONS[key]
