"""The cascaded drive controller: flat parameter/state layout and the compiled tick.

The configuration dataclasses and their loader live in feed_twin.control.config.

Structure (chain position -> velocity -> current, each loop at an integer multiple of the base
period; all positions and velocities load side, SI):

Position loop (period T_p), P with feed-forward, on the fine-interpolated NC setpoint x_r:
    v_cmd = Kv * (x_r - x_fb) + k_vff * v_r,      i_ff = k_aff * a_r * (2*pi/lead) * J_total / K_t
    x_fb = theta_enc * lead / (2*pi)   (semi-closed loop)   or   x_scale   (closed loop)
Velocity loop (period T_v), PI with clamping anti-windup and the effort (current) limit:
    i_q* = clip(Kp * (e_v + (T_v/Ti) * sum e_v) + i_ff + effort_add, +/- effort_limit)
    followed by an optional 2nd-order low-pass and an optional notch (biquads) on i_q*;
    v_est from encoder differences through a FIR on the differences and an optional low-pass.
Current loop (period T_i), FOC with d/q PI, decoupling and back-EMF feed-forward:
    i_d, i_q = Park(Clarke(i_a, i_b, i_c), theta_e),  theta_e = p * theta_enc + offset
    u_d = PI_d(0 - i_d) - omega_e * L_q * i_q
    u_q = PI_q(i_q* - i_q) + omega_e * (L_d * i_d + psi_pm)
    (u_d, u_q) limited to the circle margin * u_dc / sqrt(3) (d priority), clamping anti-windup,
    inverse Park at theta_e + advance * omega_e * T_i, optional dead-time compensation per phase
    (u_comp * clip(i_x / band, -1, 1)), SVPWM (min-max injection) -> duty cycles.
Without a current loop (ideal force/torque source such as the EMPS bench) the velocity-loop output
is the effort command itself, in the drive's input units.

Computation delay: with `computation_delay: true`, what the innermost loop computes at its sample
k is applied from its next sample (digital drives compute during one PWM period and load the
result at the next), so the output vector carries the previous result.

Boundary modes (CiA 402): `position` (CSP, all loops here), `velocity` (CSV: REF_VEL_EXT_M_S in,
no position loop), `torque` (CST: REF_I_Q_EXT_A in, only the current loop). The mode is a slot of
the parameter vector, so one configuration serves the ROS controller node (outer loops) and the
simulated drive (current loop) with the same kernels.

Drive behaviour: the power stage is enabled by the state slot `enable_cmd` (`enable`/`disable`),
a following error beyond its limit or a phase current beyond the trip level latches a FAULT_*
code until `clear_fault`; while disabled or faulted all integrators are held at zero, duties are
1/2 (zero voltage), the effort is 0 and OUT_ENABLED is 0.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from feed_twin.control import signals as sig
from feed_twin.control.blocks import (
    BIQUAD_IDENTITY,
    biquad_update,
    lowpass1_alpha,
    lowpass2_coefficients,
    notch_coefficients,
    pi_integrate,
    pi_update,
)
from feed_twin.control.config import (
    INTERP_HOLD,
    INTERP_LINEAR,
    INTERPOLATION_CODES,
    MODE_CODES,
    MODE_POSITION,
    MODE_TORQUE,
    MODE_VELOCITY,
    TWO_PI,
    ControllerConfig,
    Mode,
)
from feed_twin.control.transforms import (
    SQRT3,
    clarke,
    inverse_clarke,
    limit_voltage_circle,
    svpwm_phase_duties,
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
) = range(len(PARAM_NAMES))
P_FIR_TAPS = len(PARAM_NAMES)  # the FIR taps follow the fixed slots

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


def with_mode(cascade: CompiledCascade, mode: Mode) -> CompiledCascade:
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


# ---------------------------------------------------------------------------------------------
# Kernels. Only `cascade_tick` touches the arrays; the laws below take and return scalars, which
# keeps numba from reference-counting array arguments on every call inside the hot loop.


@njit(cache=True)
def due(k: int, div: float) -> bool:
    """A loop with period div (in base ticks) samples at tick k."""
    return k % int(div) == 0


@njit(cache=True)
def interpolate(
    method: int,
    frac: float,
    nc_period_s: float,
    prev: tuple[float, float, float],
    cur: tuple[float, float, float],
) -> tuple[float, float, float]:
    """Fine-interpolated (x, v, a) at the fraction `frac` of the NC period since the latest
    NC sample `cur` (x, v, a); `prev` is the sample before it."""
    if method == INTERP_HOLD:
        return cur
    if method == INTERP_LINEAR:
        # one NC period late, but continuous in x: the usual drive-side interpolator
        return (
            prev[0] + frac * (cur[0] - prev[0]),
            prev[1] + frac * (cur[1] - prev[1]),
            prev[2] + frac * (cur[2] - prev[2]),
        )
    dt = frac * nc_period_s
    return (cur[0] + cur[1] * dt + 0.5 * cur[2] * dt * dt, cur[1] + cur[2] * dt, cur[2])


@njit(cache=True)
def position_law(
    x_r: float,
    v_r: float,
    a_r: float,
    x_fb: float,
    Kv: float,
    vff: float,
    acc_ff_gain: float,
    v_limit: float,
) -> tuple[float, float, float]:
    """P position loop: (velocity command [m/s], effort feed-forward, following error [m])."""
    e = x_r - x_fb
    v_cmd = min(max(Kv * e + vff * v_r, -v_limit), v_limit)
    return v_cmd, acc_ff_gain * a_r, e


@njit(cache=True, _nrt=False)
def current_law(
    i_a: float,
    i_b: float,
    i_c: float,
    theta_e: float,
    omega_e: float,
    i_q_ref: float,
    u_dc: float,
    x_d: float,
    x_q: float,
    cp: np.ndarray,
) -> tuple[float, float, float, float, float, float, float]:
    """FOC sample: (d_a, d_b, d_c, u_d, u_q, next x_d, next x_q); x_* are the PI integrators.

    `cp` is only read; numba does not reference-count read-only parameter arrays passed on.
    """
    # one sin/cos pair serves Park and inverse Park (the advance rotates it): trigonometric
    # calls are the dearest part of the tick
    cos_e = math.cos(theta_e)
    sin_e = math.sin(theta_e)
    i_alpha, i_beta = clarke(i_a, i_b, i_c)
    i_d = cos_e * i_alpha + sin_e * i_beta
    i_q = -sin_e * i_alpha + cos_e * i_beta
    e_d = 0.0 - i_d
    e_q = i_q_ref - i_q
    dec = cp[P_DECOUPLING] * omega_e
    ff_d = -dec * cp[P_L_Q] * i_q
    ff_q = dec * cp[P_L_D] * i_d + cp[P_BACK_EMF_FF] * omega_e * cp[P_PSI_PM]
    u_d = cp[P_KP_D] * e_d + x_d + ff_d
    u_q = cp[P_KP_Q] * e_q + x_q + ff_q
    u_max = cp[P_VOLTAGE_MARGIN] * max(u_dc, 0.0) / SQRT3
    u_d_lim, u_q_lim = limit_voltage_circle(u_d, u_q, u_max)
    x_d = pi_integrate(x_d, e_d, cp[P_KI_T_D], u_d, u_d_lim)
    x_q = pi_integrate(x_q, e_q, cp[P_KI_T_Q], u_q, u_q_lim)
    advance = cp[P_ANGLE_ADVANCE] * omega_e * cp[P_CUR_PERIOD]
    if advance != 0.0:
        cos_a = math.cos(advance)
        sin_a = math.sin(advance)
        cos_e, sin_e = cos_e * cos_a - sin_e * sin_a, sin_e * cos_a + cos_e * sin_a
    u_alpha = cos_e * u_d_lim - sin_e * u_q_lim
    u_beta = sin_e * u_d_lim + cos_e * u_q_lim
    if u_dc <= 0.0:
        return 0.5, 0.5, 0.5, u_d_lim, u_q_lim, x_d, x_q
    u_a, u_b, u_c = inverse_clarke(u_alpha, u_beta)
    comp = cp[P_DEAD_TIME_COMP]
    if comp > 0.0:
        band = cp[P_DEAD_TIME_BAND]
        u_a += comp * min(max(i_a / band, -1.0), 1.0)
        u_b += comp * min(max(i_b / band, -1.0), 1.0)
        u_c += comp * min(max(i_c / band, -1.0), 1.0)
    d_a, d_b, d_c = svpwm_phase_duties(u_a, u_b, u_c, u_dc)
    return d_a, d_b, d_c, u_d_lim, u_q_lim, x_d, x_q


@njit(cache=True, _nrt=False)
def cascade_tick(
    cp: np.ndarray, cs: np.ndarray, k: int, ref: np.ndarray, meas: np.ndarray, out: np.ndarray
) -> None:
    """One base tick k of the whole cascade: read ref/meas, update cs, write every OUT_* slot.

    The loops due at tick k run outer to inner, so a new position setpoint reaches the duty
    cycles within the same tick (plus the configured computation delay).
    """
    mode = int(cp[P_MODE])
    m_per_rad = cp[P_LEAD] / TWO_PI
    x_enc = meas[sig.MEAS_THETA_ENC_RAD] * m_per_rad
    has_position = cp[P_HAS_POSITION] > 0.5
    has_velocity = cp[P_HAS_VELOCITY] > 0.5
    has_current = cp[P_HAS_CURRENT] > 0.5
    nc_div = cp[P_NC_DIV]

    if cs[S_INITIALISED] == 0.0:
        # start the interpolator at the current setpoint (latched at the last NC instant at or
        # before k) and the velocity estimator at rest
        for i in range(3):
            cs[S_NC_PREV_POS + i] = ref[sig.REF_POS_M + i]
            cs[S_NC_POS + i] = ref[sig.REF_POS_M + i]
        cs[S_NC_TICK] = k - k % int(nc_div)
        cs[S_ENC_POS_PREV] = x_enc
        cs[S_INITIALISED] = 1.0

    active = cs[S_ENABLE_CMD] > 0.5 and cs[S_FAULT] == 0.0
    if active and has_current:
        i_trip = cp[P_I_TRIP]
        if (
            abs(meas[sig.MEAS_I_A]) > i_trip
            or abs(meas[sig.MEAS_I_B]) > i_trip
            or abs(meas[sig.MEAS_I_C]) > i_trip
        ):
            cs[S_FAULT] = sig.FAULT_OVERCURRENT

    if has_position and due(k, nc_div):
        for i in range(3):
            cs[S_NC_PREV_POS + i] = cs[S_NC_POS + i]
            cs[S_NC_POS + i] = ref[sig.REF_POS_M + i]
        cs[S_NC_TICK] = k

    vel_due = has_velocity and due(k, cp[P_VEL_DIV])
    if vel_due:
        n_taps = int(cp[P_FIR_N])
        for i in range(n_taps - 1, 0, -1):
            cs[S_FIR_HIST + i] = cs[S_FIR_HIST + i - 1]
        cs[S_FIR_HIST] = (x_enc - cs[S_ENC_POS_PREV]) / cp[P_VEL_PERIOD]
        cs[S_ENC_POS_PREV] = x_enc
        v_raw = 0.0
        for i in range(n_taps):
            v_raw += cp[P_FIR_TAPS + i] * cs[S_FIR_HIST + i]
        cs[S_VEL_EST] += cp[P_VEL_LP_ALPHA] * (v_raw - cs[S_VEL_EST])

    if has_position and due(k, cp[P_POS_DIV]):
        x_r, v_r, a_r = interpolate(
            int(cp[P_INTERPOLATION]),
            (k - cs[S_NC_TICK]) / nc_div,
            nc_div * cp[P_BASE_PERIOD],
            (cs[S_NC_PREV_POS], cs[S_NC_PREV_VEL], cs[S_NC_PREV_ACC]),
            (cs[S_NC_POS], cs[S_NC_VEL], cs[S_NC_ACC]),
        )
        x_fb = meas[sig.MEAS_X_SCALE_M] if cp[P_FEEDBACK_SCALE] > 0.5 else x_enc
        v_cmd, effort_ff, e = position_law(
            x_r, v_r, a_r, x_fb, cp[P_KV], cp[P_VFF], cp[P_ACC_FF_GAIN], cp[P_V_LIMIT]
        )
        cs[S_POS_REF] = x_r
        cs[S_FOLLOWING_ERROR] = e
        cs[S_VEL_CMD] = v_cmd
        cs[S_EFFORT_FF] = effort_ff
        if active and mode == MODE_POSITION and abs(e) > cp[P_FE_LIMIT]:
            cs[S_FAULT] = sig.FAULT_FOLLOWING_ERROR

    active = cs[S_ENABLE_CMD] > 0.5 and cs[S_FAULT] == 0.0
    lim = cp[P_EFFORT_LIMIT]
    effort_add = ref[sig.REF_EFFORT_ADD]
    if mode == MODE_VELOCITY:
        cs[S_VEL_CMD] = ref[sig.REF_VEL_EXT_M_S]
        cs[S_EFFORT_FF] = 0.0
    if not active:
        # power stage off: integrators, filters and pending outputs cleared
        cs[S_VEL_INT] = 0.0
        cs[S_I_D_INT] = 0.0
        cs[S_I_Q_INT] = 0.0
        for i in range(2):
            cs[S_BQ_LP + i] = 0.0
            cs[S_BQ_NOTCH + i] = 0.0
        cs[S_EFFORT_CMD] = 0.0
        cs[S_U_D_REF] = 0.0
        cs[S_U_Q_REF] = 0.0
        for i in range(3):
            cs[S_DUTY_NEXT_A + i] = 0.5
            cs[S_DUTY_A + i] = 0.5
        cs[S_EFFORT_NEXT] = 0.0
        cs[S_EFFORT_OUT] = 0.0
    elif mode == MODE_TORQUE:
        cs[S_EFFORT_CMD] = min(max(ref[sig.REF_I_Q_EXT_A] + effort_add, -lim), lim)
    elif vel_due:
        u, cs[S_VEL_INT] = pi_update(
            cs[S_VEL_INT],
            cs[S_VEL_CMD] - cs[S_VEL_EST],
            cp[P_VEL_KP],
            cp[P_VEL_KI_T],
            cs[S_EFFORT_FF] + effort_add,
            -lim,
            lim,
        )
        for p_bq, s_bq in ((P_BQ_LP, S_BQ_LP), (P_BQ_NOTCH, S_BQ_NOTCH)):
            u, cs[s_bq], cs[s_bq + 1] = biquad_update(
                cp[p_bq],
                cp[p_bq + 1],
                cp[p_bq + 2],
                cp[p_bq + 3],
                cp[p_bq + 4],
                cs[s_bq],
                cs[s_bq + 1],
                u,
            )
        cs[S_EFFORT_CMD] = min(max(u, -lim), lim)

    delayed = cp[P_COMPUTATION_DELAY] > 0.5
    if has_current:
        if active and due(k, cp[P_CUR_DIV]):
            p = cp[P_POLE_PAIRS]
            d_a, d_b, d_c, u_d, u_q, cs[S_I_D_INT], cs[S_I_Q_INT] = current_law(
                meas[sig.MEAS_I_A],
                meas[sig.MEAS_I_B],
                meas[sig.MEAS_I_C],
                p * meas[sig.MEAS_THETA_ENC_RAD] + cp[P_ENCODER_OFFSET],
                p * cs[S_VEL_EST] / m_per_rad,
                cs[S_EFFORT_CMD],
                meas[sig.MEAS_U_DC_V],
                cs[S_I_D_INT],
                cs[S_I_Q_INT],
                cp,
            )
            cs[S_U_D_REF] = u_d
            cs[S_U_Q_REF] = u_q
            if delayed:
                cs[S_DUTY_A] = cs[S_DUTY_NEXT_A]
                cs[S_DUTY_B] = cs[S_DUTY_NEXT_B]
                cs[S_DUTY_C] = cs[S_DUTY_NEXT_C]
                cs[S_DUTY_NEXT_A] = d_a
                cs[S_DUTY_NEXT_B] = d_b
                cs[S_DUTY_NEXT_C] = d_c
            else:
                cs[S_DUTY_A] = d_a
                cs[S_DUTY_B] = d_b
                cs[S_DUTY_C] = d_c
        out[sig.OUT_EFFORT_CMD] = 0.0
    else:
        if active and (mode == MODE_TORQUE or vel_due):
            if delayed:
                cs[S_EFFORT_OUT] = cs[S_EFFORT_NEXT]
                cs[S_EFFORT_NEXT] = cs[S_EFFORT_CMD]
            else:
                cs[S_EFFORT_OUT] = cs[S_EFFORT_CMD]
        out[sig.OUT_EFFORT_CMD] = cs[S_EFFORT_OUT]

    out[sig.OUT_DUTY_A] = cs[S_DUTY_A]
    out[sig.OUT_DUTY_B] = cs[S_DUTY_B]
    out[sig.OUT_DUTY_C] = cs[S_DUTY_C]
    out[sig.OUT_I_D_REF_A] = 0.0
    out[sig.OUT_I_Q_REF_A] = cs[S_EFFORT_CMD]
    out[sig.OUT_U_D_REF_V] = cs[S_U_D_REF]
    out[sig.OUT_U_Q_REF_V] = cs[S_U_Q_REF]
    out[sig.OUT_POS_REF_M] = cs[S_POS_REF]
    out[sig.OUT_VEL_REF_M_S] = cs[S_VEL_CMD]
    out[sig.OUT_VEL_EST_M_S] = cs[S_VEL_EST]
    out[sig.OUT_FOLLOWING_ERROR_M] = cs[S_FOLLOWING_ERROR]
    if cs[S_FAULT] != 0.0:
        out[sig.OUT_FAULT] = cs[S_FAULT]
    elif cs[S_ENABLE_CMD] <= 0.5:
        out[sig.OUT_FAULT] = sig.FAULT_DISABLED
    else:
        out[sig.OUT_FAULT] = sig.FAULT_NONE
    out[sig.OUT_ENABLED] = 1.0 if active else 0.0


def source_digest() -> str:
    """Hash of the controller's kernel sources, for caches of code that inlines `cascade_tick`
    (numba's cache of a caller does not notice changes in callees from other modules)."""
    digest = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in ("cascade.py", "config.py", "blocks.py", "transforms.py", "signals.py"):
        digest.update((here / name).read_bytes())
    return digest.hexdigest()[:20]
