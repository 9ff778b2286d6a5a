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

from feed_twin.control import signals as sig
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

# ---------------------------------------------------------------------------------------------
# Flat layouts. Unpacking `range` over the name tuple keeps constants and names in step (a
# mismatch fails at import); numba folds these module integers into the kernels.

PARAM_NAMES = (
    "base_period_s",
    "mode",
    "computation_delay",
    "nc_div",
    "lead_m",
    "effort_limit",
    "has_position",
    "pos_div",
    "Kv_1_s",
    "velocity_ff",
    "acc_ff_gain",
    "feedback_scale",
    "interpolation",
    "fe_limit_m",
    "v_limit_m_s",
    "has_velocity",
    "vel_div",
    "vel_period_s",
    "vel_Kp",
    "vel_Ki_T",
    "vel_lowpass_alpha",
    "fir_n",
    "bq_lp_b0",
    "bq_lp_b1",
    "bq_lp_b2",
    "bq_lp_a1",
    "bq_lp_a2",
    "bq_notch_b0",
    "bq_notch_b1",
    "bq_notch_b2",
    "bq_notch_a1",
    "bq_notch_a2",
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
    "decoupling",
    "back_emf_ff",
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
(
    P_BASE_PERIOD,
    P_MODE,
    P_COMPUTATION_DELAY,
    P_NC_DIV,
    P_LEAD,
    P_EFFORT_LIMIT,
    P_HAS_POSITION,
    P_POS_DIV,
    P_KV,
    P_VFF,
    P_ACC_FF_GAIN,
    P_FEEDBACK_SCALE,
    P_INTERPOLATION,
    P_FE_LIMIT,
    P_V_LIMIT,
    P_HAS_VELOCITY,
    P_VEL_DIV,
    P_VEL_PERIOD,
    P_VEL_KP,
    P_VEL_KI_T,
    P_VEL_LP_ALPHA,
    P_FIR_N,
    P_BQ_LP,
    _P_BQ_LP_1,
    _P_BQ_LP_2,
    _P_BQ_LP_3,
    _P_BQ_LP_4,
    P_BQ_NOTCH,
    _P_BQ_NOTCH_1,
    _P_BQ_NOTCH_2,
    _P_BQ_NOTCH_3,
    _P_BQ_NOTCH_4,
    P_HAS_CURRENT,
    P_CUR_DIV,
    P_CUR_PERIOD,
    P_POLE_PAIRS,
    P_L_D,
    P_L_Q,
    P_PSI_PM,
    P_KP_D,
    P_KI_T_D,
    P_KP_Q,
    P_KI_T_Q,
    P_DECOUPLING,
    P_BACK_EMF_FF,
    P_VOLTAGE_MARGIN,
    P_ANGLE_ADVANCE,
    P_ENCODER_OFFSET,
    P_I_TRIP,
    P_DEAD_TIME_COMP,
    P_DEAD_TIME_BAND,
    P_M_PER_RAD,
    P_RAD_PER_M,
    P_VEL_RATE,
    P_NC_DIV_INV,
) = range(len(PARAM_NAMES))
P_FIR_TAPS = len(PARAM_NAMES)  # the FIR taps follow the fixed slots

# The cascade's structure: its mode, which loops exist and at what rates, the feedback source,
# the interpolation, the FIR's length and the computation delay. The engine compiles these slots
# into its kernel as constants (one kernel per structure, as a Modelica tool evaluates structural
# parameters), so the tick has no branch on them; every other slot is read as the loop runs.
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
    "has_velocity",
    "vel_div",
    "fir_n",
    "has_current",
    "cur_div",
)
STRUCTURE_SLOTS = tuple(PARAM_NAMES.index(n) for n in STRUCTURE_NAMES)

STATE_NAMES = (
    "initialised",
    "enable_cmd",
    "fault",
    "nc_tick",
    "nc_prev_pos_m",
    "nc_prev_vel_m_s",
    "nc_prev_acc_m_s2",
    "nc_pos_m",
    "nc_vel_m_s",
    "nc_acc_m_s2",
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
    "duty_next_a",
    "duty_next_b",
    "duty_next_c",
    "duty_a",
    "duty_b",
    "duty_c",
    "effort_next",
    "effort_out",
    "park_anchor_rad",
    "park_anchor_cos",
    "park_anchor_sin",
)
(
    S_INITIALISED,
    S_ENABLE_CMD,
    S_FAULT,
    S_NC_TICK,
    S_NC_PREV_POS,
    S_NC_PREV_VEL,
    S_NC_PREV_ACC,
    S_NC_POS,
    S_NC_VEL,
    S_NC_ACC,
    S_POS_REF,
    S_FOLLOWING_ERROR,
    S_VEL_CMD,
    S_EFFORT_FF,
    S_VEL_EST,
    S_ENC_POS_PREV,
    S_VEL_INT,
    S_EFFORT_CMD,
    S_BQ_LP,
    _S_BQ_LP_2,
    S_BQ_NOTCH,
    _S_BQ_NOTCH_2,
    S_I_D_INT,
    S_I_Q_INT,
    S_U_D_REF,
    S_U_Q_REF,
    S_DUTY_NEXT_A,
    S_DUTY_NEXT_B,
    S_DUTY_NEXT_C,
    S_DUTY_A,
    S_DUTY_B,
    S_DUTY_C,
    S_EFFORT_NEXT,
    S_EFFORT_OUT,
    S_PARK_ANCHOR,  # the last electrical angle whose sine and cosine were evaluated in full
    _S_PARK_ANCHOR_COS,  # and that pair (feed_twin.plant.trig.sincos_anchored)
    _S_PARK_ANCHOR_SIN,
) = range(len(STATE_NAMES))
S_FIR_HIST = len(STATE_NAMES)  # the FIR difference history follows the fixed slots


# ---------------------------------------------------------------------------------------------
# Building the parameter vector


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
        cs[S_ENABLE_CMD] = 1.0 if self.config.enabled_at_start else 0.0
        cs[S_DUTY_NEXT_A : S_DUTY_C + 1] = 0.5
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
    p[P_COMPUTATION_DELAY] = float(config.computation_delay)
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
        p[P_HAS_POSITION] = 1.0
        p[P_POS_DIV] = round(pos.period_s / base)
        p[P_KV] = pos.Kv_1_s
        p[P_VFF] = pos.velocity_ff
        # a [m/s^2] -> motor angular acceleration -> torque J*alpha -> effort torque/K_t
        p[P_ACC_FF_GAIN] = (
            pos.acceleration_ff * (TWO_PI / drive.lead_m) * (drive.J_total_kg_m2 / drive.K_t)
        )
        p[P_FEEDBACK_SCALE] = 1.0 if pos.feedback == "linear_scale" else 0.0
        p[P_INTERPOLATION] = INTERPOLATION_CODES[pos.interpolation]
        if pos.following_error_limit_m is not None:
            p[P_FE_LIMIT] = pos.following_error_limit_m
        if pos.velocity_limit_m_s is not None:
            p[P_V_LIMIT] = pos.velocity_limit_m_s
    vel = config.velocity
    if vel is not None:
        T_v = vel.period_s
        p[P_HAS_VELOCITY] = 1.0
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
        p[P_HAS_CURRENT] = 1.0
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


# ---------------------------------------------------------------------------------------------
# Drive commands on a state vector (what a CiA 402 controlword does)


def enable(cs: np.ndarray) -> None:
    """Request the power stage on (takes effect at the next tick unless a fault is latched)."""
    cs[S_ENABLE_CMD] = 1.0


def disable(cs: np.ndarray) -> None:
    """Request the power stage off; integrators are cleared at the next tick."""
    cs[S_ENABLE_CMD] = 0.0


def clear_fault(cs: np.ndarray) -> None:
    """Acknowledge a latched fault (fault reset)."""
    cs[S_FAULT] = 0.0


def fault_reason(code: float) -> str:
    """Text of a FAULT_* code as found in OUT_FAULT."""
    key = int(code)
    if key not in sig.FAULT_REASONS:
        raise ValueError(f"fault code = {code!r}: unknown; known: {sorted(sig.FAULT_REASONS)}")
    return sig.FAULT_REASONS[key]
