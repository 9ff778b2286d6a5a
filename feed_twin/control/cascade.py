# pyright: reportUntypedFunctionDecorator=false
# (numba's njit carries no types; the laws are typed by their own annotations)
"""The cascaded drive controller: the compiled tick.

The configuration dataclasses and their loader live in feed_twin.control.config; the flat
parameter and state vectors the tick reads and writes (P_*/S_* slots, `build_cascade`, the drive
commands) in feed_twin.control.layout.

Structure (chain position -> velocity -> current, each loop at an integer multiple of the base
period; all positions and velocities load side, SI):

Position loop (period T_p), P with feed-forward, on the fine-interpolated NC setpoint x_r:
    v_cmd = Kv * (x_r - x_fb) + k_vff * v_r,      i_ff = k_aff * a_r * (2*pi/lead) * J_total / K_t
    (x_r, v_r, a_r from the NC samples held, linearly or cubically (Hermite) interpolated one NC
    period late, or extrapolated; with `feed_forward_rate: velocity` v_r and a_r are
    interpolated anew at every velocity-loop sample, Kv * (x_r - x_fb) held between)
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

import hashlib
from pathlib import Path

import numpy as np
from numba import njit

from feed_twin.control import layout as lay
from feed_twin.control.blocks import biquad_update, pi_integrate, pi_update
from feed_twin.control.config import (
    INTERP_CUBIC,
    INTERP_HOLD,
    INTERP_LINEAR,
    MODE_POSITION,
    MODE_TORQUE,
    MODE_VELOCITY,
)
from feed_twin.control.transforms import SQRT3, clarke, limit_voltage_circle, modulate
from feed_twin.core import signals as sig
from feed_twin.core.trig import sincos, sincos_anchored

# The laws (due, interpolate, position_law, current_law) take and return scalars. The stages of
# `cascade_tick` read and write the arrays; numba inlines them into the tick's own IR
# (inline="always"), so the tick compiles as one function without reference counting, as it
# did when it was written as one: compiled apart and inlined by LLVM, the FIR loop came out
# unrolled otherwise and the tick 5 % longer.


@njit(forceinline=True)
def due(k: int, div: float) -> bool:
    """A loop with period div (in base ticks) samples at tick k >= 0."""
    d = int(div)
    if d & (d - 1) == 0:
        # the usual rates are the base rate over a power of two: a mask instead of an integer
        # division, of which the tick would otherwise pay four
        return k & (d - 1) == 0
    return k % d == 0


@njit(forceinline=True)
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
    if method == INTERP_CUBIC:
        return hermite(frac, nc_period_s, prev, cur)
    dt = frac * nc_period_s
    return (cur[0] + cur[1] * dt + 0.5 * cur[2] * dt * dt, cur[1] + cur[2] * dt, cur[2])


@njit(forceinline=True)
def hermite(
    s: float, span_s: float, prev: tuple[float, float, float], cur: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Cubic Hermite spline from `prev` (s = 0) to `cur` (s = 1) through both samples' positions
    with both samples' velocities, over span_s: (x, dx/dt, d2x/dt2) at the fraction s. One NC
    period late like the linear interpolator, but its position follows the curve the velocities
    describe (the linear one runs on the chord) and its velocity is that curve's slope."""
    s2 = s * s
    s3 = s2 * s
    x0, v0 = prev[0], prev[1] * span_s  # the slopes per unit of s
    x1, v1 = cur[0], cur[1] * span_s
    x = (2.0 * s3 - 3.0 * s2 + 1.0) * x0 + (s3 - 2.0 * s2 + s) * v0
    x += (3.0 * s2 - 2.0 * s3) * x1 + (s3 - s2) * v1
    dx = (
        (6.0 * s2 - 6.0 * s) * (x0 - x1)
        + (3.0 * s2 - 4.0 * s + 1.0) * v0
        + (3.0 * s2 - 2.0 * s) * v1
    )
    ddx = (12.0 * s - 6.0) * (x0 - x1) + (6.0 * s - 4.0) * v0 + (6.0 * s - 2.0) * v1
    return x, dx / span_s, ddx / (span_s * span_s)


@njit(forceinline=True)
def velocity_command(e: float, v_r: float, Kv: float, vff: float, v_limit: float) -> float:
    """The position loop's velocity command from its following error e and the speed v_r."""
    return min(max(Kv * e + vff * v_r, -v_limit), v_limit)


@njit(forceinline=True)
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
    return velocity_command(e, v_r, Kv, vff, v_limit), acc_ff_gain * a_r, e


@njit(_nrt=False, forceinline=True)  # pyright: ignore[reportCallIssue]  numba-only options
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
    anchor: tuple[float, float, float],
    cp: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, tuple[float, float, float]]:
    """FOC sample: (d_a, d_b, d_c, u_d, u_q, next x_d, next x_q, next anchor); x_* are the PI
    integrators, `anchor` the last angle evaluated in full and its (cos, sin). The voltages
    reach the duties through `transforms.modulate`, at the angle advanced by the delay.

    `cp` is only read; numba does not reference-count read-only parameter arrays passed on.
    """
    # one sin/cos pair serves Park and inverse Park (the advance rotates it): trigonometric
    # calls are the dearest part of the tick, so the pair is rotated from the anchor while the
    # rotor stays within trig.NEAR of it (16 ticks at 600 rpm)
    cos_e, sin_e, a_theta, a_cos, a_sin = sincos_anchored(theta_e, anchor[0], anchor[1], anchor[2])
    anchor = (a_theta, a_cos, a_sin)
    i_alpha, i_beta = clarke(i_a, i_b, i_c)
    i_d = cos_e * i_alpha + sin_e * i_beta
    i_q = -sin_e * i_alpha + cos_e * i_beta
    e_d = 0.0 - i_d
    e_q = i_q_ref - i_q
    dec = cp[lay.P_DECOUPLING] * omega_e
    ff_d = -dec * cp[lay.P_L_Q] * i_q
    ff_q = dec * cp[lay.P_L_D] * i_d + cp[lay.P_BACK_EMF_FF] * omega_e * cp[lay.P_PSI_PM]
    u_d = cp[lay.P_KP_D] * e_d + x_d + ff_d
    u_q = cp[lay.P_KP_Q] * e_q + x_q + ff_q
    u_max = cp[lay.P_VOLTAGE_MARGIN] * max(u_dc, 0.0) * (1.0 / SQRT3)
    u_d_lim, u_q_lim = limit_voltage_circle(u_d, u_q, u_max)
    x_d = pi_integrate(x_d, e_d, cp[lay.P_KI_T_D], u_d, u_d_lim)
    x_q = pi_integrate(x_q, e_q, cp[lay.P_KI_T_Q], u_q, u_q_lim)
    advance = cp[lay.P_ANGLE_ADVANCE] * omega_e * cp[lay.P_CUR_PERIOD]
    if advance != 0.0:
        cos_a, sin_a = sincos(advance)
        cos_e, sin_e = cos_e * cos_a - sin_e * sin_a, sin_e * cos_a + cos_e * sin_a
    d_a, d_b, d_c = modulate(
        u_d_lim,
        u_q_lim,
        cos_e,
        sin_e,
        i_a,
        i_b,
        i_c,
        cp[lay.P_DEAD_TIME_COMP],
        cp[lay.P_DEAD_TIME_BAND],
        u_dc,
    )
    return d_a, d_b, d_c, u_d_lim, u_q_lim, x_d, x_q, anchor


@njit(inline="always")
def is_active(cs: np.ndarray) -> bool:
    """The power stage is on: requested (enable_cmd) and no fault latched."""
    return cs[lay.S_ENABLE_CMD] == lay.STAGE_ON and cs[lay.S_FAULT] == sig.FAULT_NONE


@njit(inline="always")
def start(cs: np.ndarray, k: int, ref: np.ndarray, x_enc: float, nc_div: float) -> None:
    """First tick: the interpolator at the current setpoint (latched at the last NC instant at
    or before k), the velocity estimator at rest."""
    for i in range(3):
        cs[lay.S_NC_PREV_POS + i] = ref[sig.REF_POS_M + i]
        cs[lay.S_NC_POS + i] = ref[sig.REF_POS_M + i]
    cs[lay.S_NC_TICK] = k - k % int(nc_div)
    cs[lay.S_ENC_POS_PREV] = x_enc
    cs[lay.S_INITIALISED] = lay.STARTED


@njit(inline="always")
def trip_overcurrent(cp: np.ndarray, cs: np.ndarray, meas: np.ndarray) -> None:
    """Latch FAULT_OVERCURRENT when a measured phase current exceeds the trip level."""
    i_trip = cp[lay.P_I_TRIP]
    if (
        abs(meas[sig.MEAS_I_A]) > i_trip
        or abs(meas[sig.MEAS_I_B]) > i_trip
        or abs(meas[sig.MEAS_I_C]) > i_trip
    ):
        cs[lay.S_FAULT] = sig.FAULT_OVERCURRENT


@njit(inline="always")
def latch_nc_sample(cs: np.ndarray, k: int, ref: np.ndarray) -> None:
    """An NC instant: the latest (x, v, a) setpoint becomes the previous one."""
    for i in range(3):
        cs[lay.S_NC_PREV_POS + i] = cs[lay.S_NC_POS + i]
        cs[lay.S_NC_POS + i] = ref[sig.REF_POS_M + i]
    cs[lay.S_NC_TICK] = k


@njit(inline="always")
def estimate_velocity(cp: np.ndarray, cs: np.ndarray, x_enc: float) -> None:
    """Encoder difference quotient through the FIR on the differences and the low-pass."""
    n_taps = int(cp[lay.P_FIR_N])
    for i in range(n_taps - 1, 0, -1):
        cs[lay.S_FIR_HIST + i] = cs[lay.S_FIR_HIST + i - 1]
    cs[lay.S_FIR_HIST] = (x_enc - cs[lay.S_ENC_POS_PREV]) * cp[lay.P_VEL_RATE]
    cs[lay.S_ENC_POS_PREV] = x_enc
    v_raw = 0.0
    for i in range(n_taps):
        v_raw += cp[lay.P_FIR_TAPS + i] * cs[lay.S_FIR_HIST + i]
    cs[lay.S_VEL_EST] += cp[lay.P_VEL_LP_ALPHA] * (v_raw - cs[lay.S_VEL_EST])


@njit(inline="always")
def setpoint(cp: np.ndarray, cs: np.ndarray, k: int) -> tuple[float, float, float]:
    """The fine-interpolated NC setpoint (x, v, a) at tick k."""
    return interpolate(
        int(cp[lay.P_INTERPOLATION]),
        (k - cs[lay.S_NC_TICK]) * cp[lay.P_NC_DIV_INV],
        cp[lay.P_NC_DIV] * cp[lay.P_BASE_PERIOD],
        (cs[lay.S_NC_PREV_POS], cs[lay.S_NC_PREV_POS + 1], cs[lay.S_NC_PREV_POS + 2]),
        (cs[lay.S_NC_POS], cs[lay.S_NC_POS + 1], cs[lay.S_NC_POS + 2]),
    )


@njit(inline="always")
def refresh_feed_forward(cp: np.ndarray, cs: np.ndarray, k: int) -> None:
    """A velocity-loop sample between position-loop samples (feed_forward_rate: velocity): the
    speed and acceleration feed-forwards fine-interpolated anew, the position loop's own part
    (Kv times its latest following error) held."""
    _, v_r, a_r = setpoint(cp, cs, k)
    cs[lay.S_VEL_CMD] = velocity_command(
        cs[lay.S_FOLLOWING_ERROR], v_r, cp[lay.P_KV], cp[lay.P_VFF], cp[lay.P_V_LIMIT]
    )
    cs[lay.S_EFFORT_FF] = cp[lay.P_ACC_FF_GAIN] * a_r


@njit(inline="always")
def position_loop(
    cp: np.ndarray,
    cs: np.ndarray,
    k: int,
    meas: np.ndarray,
    x_enc: float,
    watch_following_error: bool,
) -> None:
    """Fine interpolation of the NC setpoint and the P position loop; latches
    FAULT_FOLLOWING_ERROR beyond the limit when `watch_following_error`."""
    x_r, v_r, a_r = setpoint(cp, cs, k)
    closed = cp[lay.P_FEEDBACK_SCALE] == lay.FEEDBACK_SCALE
    x_fb = meas[sig.MEAS_X_SCALE_M] if closed else x_enc
    v_cmd, effort_ff, e = position_law(
        x_r,
        v_r,
        a_r,
        x_fb,
        cp[lay.P_KV],
        cp[lay.P_VFF],
        cp[lay.P_ACC_FF_GAIN],
        cp[lay.P_V_LIMIT],
    )
    cs[lay.S_POS_REF] = x_r
    cs[lay.S_FOLLOWING_ERROR] = e
    cs[lay.S_VEL_CMD] = v_cmd
    cs[lay.S_EFFORT_FF] = effort_ff
    if watch_following_error and abs(e) > cp[lay.P_FE_LIMIT]:
        cs[lay.S_FAULT] = sig.FAULT_FOLLOWING_ERROR


@njit(inline="always")
def power_stage_off(cs: np.ndarray) -> None:
    """Power stage off: integrators, filters and pending outputs cleared, duties 1/2."""
    cs[lay.S_VEL_INT] = 0.0
    cs[lay.S_I_D_INT] = 0.0
    cs[lay.S_I_Q_INT] = 0.0
    for i in range(2):
        cs[lay.S_BQ_LP + i] = 0.0
        cs[lay.S_BQ_NOTCH + i] = 0.0
    cs[lay.S_EFFORT_CMD] = 0.0
    cs[lay.S_U_D_REF] = 0.0
    cs[lay.S_U_Q_REF] = 0.0
    for i in range(3):
        cs[lay.S_DUTY_NEXT + i] = 0.5
        cs[lay.S_DUTY + i] = 0.5
    cs[lay.S_EFFORT_NEXT] = 0.0
    cs[lay.S_EFFORT_OUT] = 0.0


@njit(inline="always")
def velocity_loop(cp: np.ndarray, cs: np.ndarray, effort_add: float) -> None:
    """PI velocity loop with the effort limit, then the set-point low-pass and the notch."""
    lim = cp[lay.P_EFFORT_LIMIT]
    u, cs[lay.S_VEL_INT] = pi_update(
        cs[lay.S_VEL_INT],
        cs[lay.S_VEL_CMD] - cs[lay.S_VEL_EST],
        cp[lay.P_VEL_KP],
        cp[lay.P_VEL_KI_T],
        cs[lay.S_EFFORT_FF] + effort_add,
        -lim,
        lim,
    )
    for p_bq, s_bq in ((lay.P_BQ_LP, lay.S_BQ_LP), (lay.P_BQ_NOTCH, lay.S_BQ_NOTCH)):
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
    cs[lay.S_EFFORT_CMD] = min(max(u, -lim), lim)


@njit(inline="always")
def current_loop(cp: np.ndarray, cs: np.ndarray, meas: np.ndarray, delayed: bool) -> None:
    """One FOC sample (`current_law`) into the state: integrators, Park anchor, voltages and
    the duties, applied now or, `delayed`, from the next sample."""
    p = cp[lay.P_POLE_PAIRS]
    a = lay.S_PARK_ANCHOR
    d_a, d_b, d_c, u_d, u_q, cs[lay.S_I_D_INT], cs[lay.S_I_Q_INT], anchor = current_law(
        meas[sig.MEAS_I_A],
        meas[sig.MEAS_I_B],
        meas[sig.MEAS_I_C],
        p * meas[sig.MEAS_THETA_ENC_RAD] + cp[lay.P_ENCODER_OFFSET],
        p * cs[lay.S_VEL_EST] * cp[lay.P_RAD_PER_M],
        cs[lay.S_EFFORT_CMD],
        meas[sig.MEAS_U_DC_V],
        cs[lay.S_I_D_INT],
        cs[lay.S_I_Q_INT],
        (cs[a], cs[a + 1], cs[a + 2]),
        cp,
    )
    cs[a], cs[a + 1], cs[a + 2] = anchor
    cs[lay.S_U_D_REF] = u_d
    cs[lay.S_U_Q_REF] = u_q
    if delayed:
        for i in range(3):
            cs[lay.S_DUTY + i] = cs[lay.S_DUTY_NEXT + i]
    d = lay.S_DUTY_NEXT if delayed else lay.S_DUTY
    cs[d] = d_a
    cs[d + 1] = d_b
    cs[d + 2] = d_c


@njit(inline="always")
def effort_output(cs: np.ndarray, delayed: bool) -> None:
    """Without a current loop: the effort command becomes the output, now or (`delayed`) from
    the next sample of the innermost loop."""
    if delayed:
        cs[lay.S_EFFORT_OUT] = cs[lay.S_EFFORT_NEXT]
        cs[lay.S_EFFORT_NEXT] = cs[lay.S_EFFORT_CMD]
    else:
        cs[lay.S_EFFORT_OUT] = cs[lay.S_EFFORT_CMD]


@njit(inline="always")
def write_outputs(cs: np.ndarray, out: np.ndarray, active: bool) -> None:
    """Every OUT_* slot but the effort command, from the state."""
    out[sig.OUT_DUTY_A] = cs[lay.S_DUTY]
    out[sig.OUT_DUTY_B] = cs[lay.S_DUTY + 1]
    out[sig.OUT_DUTY_C] = cs[lay.S_DUTY + 2]
    out[sig.OUT_I_D_REF_A] = 0.0
    out[sig.OUT_I_Q_REF_A] = cs[lay.S_EFFORT_CMD]
    out[sig.OUT_U_D_REF_V] = cs[lay.S_U_D_REF]
    out[sig.OUT_U_Q_REF_V] = cs[lay.S_U_Q_REF]
    out[sig.OUT_POS_REF_M] = cs[lay.S_POS_REF]
    out[sig.OUT_VEL_REF_M_S] = cs[lay.S_VEL_CMD]
    out[sig.OUT_VEL_EST_M_S] = cs[lay.S_VEL_EST]
    out[sig.OUT_FOLLOWING_ERROR_M] = cs[lay.S_FOLLOWING_ERROR]
    if cs[lay.S_FAULT] != sig.FAULT_NONE:
        out[sig.OUT_FAULT] = cs[lay.S_FAULT]
    elif cs[lay.S_ENABLE_CMD] != lay.STAGE_ON:
        out[sig.OUT_FAULT] = sig.FAULT_DISABLED
    else:
        out[sig.OUT_FAULT] = sig.FAULT_NONE
    out[sig.OUT_ENABLED] = 1.0 if active else 0.0


@njit(cache=True, _nrt=False)  # pyright: ignore[reportCallIssue]  numba-only options
def cascade_tick(
    cp: np.ndarray, cs: np.ndarray, k: int, ref: np.ndarray, meas: np.ndarray, out: np.ndarray
) -> None:
    """One base tick k of the whole cascade: read ref/meas, update cs, write every OUT_* slot.

    The loops due at tick k run outer to inner, so a new position setpoint reaches the duty
    cycles within the same tick (plus the configured computation delay).
    """
    mode = int(cp[lay.P_MODE])
    x_enc = meas[sig.MEAS_THETA_ENC_RAD] * cp[lay.P_M_PER_RAD]
    has_position = cp[lay.P_HAS_POSITION] == lay.LOOP_PRESENT
    has_current = cp[lay.P_HAS_CURRENT] == lay.LOOP_PRESENT
    delayed = cp[lay.P_COMPUTATION_DELAY] == lay.DELAY_ONE_SAMPLE
    if cs[lay.S_INITIALISED] == lay.PENDING:
        start(cs, k, ref, x_enc, cp[lay.P_NC_DIV])
    # the monitors watch the stage as it was when the tick began
    active = is_active(cs)
    if active and has_current:
        trip_overcurrent(cp, cs, meas)
    if has_position and due(k, cp[lay.P_NC_DIV]):
        latch_nc_sample(cs, k, ref)
    vel_due = cp[lay.P_HAS_VELOCITY] == lay.LOOP_PRESENT and due(k, cp[lay.P_VEL_DIV])
    if vel_due:
        estimate_velocity(cp, cs, x_enc)
    if has_position and due(k, cp[lay.P_POS_DIV]):
        position_loop(cp, cs, k, meas, x_enc, active and mode == MODE_POSITION)
    elif has_position and vel_due and cp[lay.P_FF_RATE] == lay.FF_AT_VELOCITY:
        refresh_feed_forward(cp, cs, k)

    active = is_active(cs)
    if mode == MODE_VELOCITY:
        cs[lay.S_VEL_CMD] = ref[sig.REF_VEL_EXT_M_S]
        cs[lay.S_EFFORT_FF] = 0.0
    if not active:
        power_stage_off(cs)
    elif mode == MODE_TORQUE:
        lim = cp[lay.P_EFFORT_LIMIT]
        effort = ref[sig.REF_I_Q_EXT_A] + ref[sig.REF_EFFORT_ADD]
        cs[lay.S_EFFORT_CMD] = min(max(effort, -lim), lim)
    elif vel_due:
        velocity_loop(cp, cs, ref[sig.REF_EFFORT_ADD])

    if has_current:
        if active and due(k, cp[lay.P_CUR_DIV]):
            current_loop(cp, cs, meas, delayed)
        out[sig.OUT_EFFORT_CMD] = 0.0
    else:
        if active and (mode == MODE_TORQUE or vel_due):
            effort_output(cs, delayed)
        out[sig.OUT_EFFORT_CMD] = cs[lay.S_EFFORT_OUT]
    write_outputs(cs, out, active)


def source_digest() -> str:
    """Hash of the controller's kernel sources, for caches of code that inlines `cascade_tick`
    (numba's cache of a caller does not notice changes in callees from other modules)."""
    digest = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in ("cascade.py", "layout.py", "config.py", "blocks.py", "transforms.py"):
        digest.update((here / name).read_bytes())
    for name in ("signals.py", "trig.py", "fma.py"):
        digest.update((here.parent / "core" / name).read_bytes())
    return digest.hexdigest()[:20]
