"""The truth machine's time loop (numba), from the equations in feed_twin.truth.machine.

One iteration is one current-loop period T_i: the loops sample, the current PI computes a
voltage that the inverter applies during the NEXT period (computation delay), and the plant is
integrated over `substeps` steps of semi-implicit (symplectic) Euler: velocities first, then
positions with the new velocities. The Karnopp stick test runs on each step: a table at rest
(|v| < V_STICK) whose applied force is below the holding force stays at rest, the friction
balancing it. The electrical state advances with the exact solution of its R-L equation over
the step with the back-EMF and cross coupling held, so the L/R pole sets no step limit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from feed_twin.truth.machine import G_N_KG, Machine

V_STICK = 1.0e-5  # [m/s] speed below which a Karnopp table counts as at rest
TWO_PI_3 = 2.0 * math.pi / 3.0


class KernelParams(NamedTuple):
    """Machine as the flat float tuple the compiled loop takes (field names as Machine's)."""

    R_s: float
    L_s: float
    psi: float  # true flux (data sheet * kt_scale) [V s]
    p: float
    J_m: float
    b_m: float
    u_dc: float
    dead_volts: float  # t_dead * f_pwm * u_dc [V]
    cog_n: float
    cog_A: float
    cog_phase: float
    off_a: float
    off_b: float
    off_c: float
    k_c: float
    d_c: float
    J_s: float
    lead: float
    k_bearing: float
    EA: float
    x_0: float
    d_ax: float
    half_gap: float
    lead_A: float
    lead_phase: float
    heating: float
    tau_th: float
    alpha: float
    m: float
    F_c_pos: float
    F_c_neg: float
    F_v_pos: float
    F_v_neg: float
    dF_s: float
    v_s: float
    v_reg: float
    F_hold: float
    drift: float
    F_const: float  # gravity on the unbalanced mass + the external force, +x [N]
    T_i: float
    n_sub: float
    n_vel: float  # current periods per velocity period
    n_pos: float  # velocity periods per position period
    Kp_i: float
    Ki_i: float  # Kp_i / Ti_i
    Kp_v: float
    Ki_v: float
    Kv: float
    vff: float
    i_max: float
    counts: float
    delay_periods: float  # feedback delay in current periods


def kernel_params(mc: Machine) -> KernelParams:
    n_vel = round(mc.f_current_hz / mc.f_velocity_hz)
    n_pos = round(mc.f_velocity_hz / mc.f_position_hz)
    return KernelParams(
        R_s=mc.R_s,
        L_s=mc.L_s,
        psi=mc.psi_pm * mc.kt_scale,
        p=float(mc.pole_pairs),
        J_m=mc.J_m,
        b_m=mc.b_m,
        u_dc=mc.u_dc,
        dead_volts=mc.t_dead * mc.f_pwm * mc.u_dc,
        cog_n=float(mc.cogging_order),
        cog_A=mc.cogging_Nm,
        cog_phase=mc.cogging_phase,
        off_a=mc.offset_a,
        off_b=mc.offset_b,
        off_c=mc.offset_c,
        k_c=mc.k_c,
        d_c=mc.d_c,
        J_s=mc.J_s,
        lead=mc.lead,
        k_bearing=mc.k_bearing,
        EA=mc.EA,
        x_0=mc.x_0,
        d_ax=mc.d_ax,
        half_gap=0.5 * mc.backlash,
        lead_A=mc.lead_error_m,
        lead_phase=mc.lead_error_phase,
        heating=mc.heating_K_m,
        tau_th=mc.thermal_tau_s,
        alpha=mc.alpha_K,
        m=mc.m_table,
        F_c_pos=mc.F_c_pos,
        F_c_neg=mc.F_c_neg,
        F_v_pos=mc.F_v_pos,
        F_v_neg=mc.F_v_neg,
        dF_s=mc.dF_s,
        v_s=mc.v_s,
        v_reg=mc.v_reg,
        F_hold=mc.F_hold,
        drift=mc.friction_drift_per_s,
        F_const=mc.F_ext - mc.m_unbalanced * G_N_KG,
        T_i=1.0 / mc.f_current_hz,
        n_sub=float(mc.substeps),
        n_vel=float(n_vel),
        n_pos=float(n_pos),
        Kp_i=mc.Kp_i,
        Ki_i=mc.Kp_i / mc.Ti_i,
        Kp_v=mc.Kp_v,
        Ki_v=mc.Kp_v / mc.Ti_v,
        Kv=mc.Kv,
        vff=mc.velocity_ff,
        i_max=mc.i_max,
        counts=float(mc.encoder_counts),
        delay_periods=float(round(mc.feedback_delay_s * mc.f_current_hz)),
    )


# output channels of `run`, one column each, sampled once per current period (at its end)
CHANNELS = ("x_table_m", "x_motor_m", "i_q_meas_A", "i_q_ref_A", "u_q_V", "i_q_A", "f_friction_N")


@njit(cache=True)
def _sliding_friction(P: KernelParams, v: float, t: float) -> float:
    """Friction force against the motion (Coulomb + Stribeck + viscous per direction) [N]."""
    grow = 1.0 + P.drift * t
    sgn = 2.0 / math.pi * math.atan(v / P.v_reg)
    coulomb = P.F_c_pos if v >= 0.0 else P.F_c_neg
    viscous = P.F_v_pos if v >= 0.0 else P.F_v_neg
    stribeck = P.dF_s * math.exp(-((v / P.v_s) ** 2))
    return grow * (sgn * (coulomb + stribeck) + viscous * v)


@njit(cache=True)
def _axial_force(P: KernelParams, x_nut: float, x_t: float, v_nut: float, v_t: float) -> float:
    """Force of the screw on the table through the axial spring and the backlash [N]."""
    delta = x_nut - x_t
    if delta > P.half_gap:
        spring = delta - P.half_gap
    elif delta < -P.half_gap:
        spring = delta + P.half_gap
    else:
        return 0.0
    k = 1.0 / (1.0 / P.k_bearing + (P.x_0 + x_t) / P.EA)
    return k * spring + P.d_ax * (v_nut - v_t)


@njit(cache=True)
def run(P: KernelParams, x_ref: np.ndarray, v_ref: np.ndarray, x0: float) -> np.ndarray:
    """Simulate len(x_ref) current periods from rest at x0; x_ref, v_ref: the position setpoint
    [m] and its speed [m/s] at the start of each current period. Returns (n, len(CHANNELS))."""
    n = len(x_ref)
    out = np.zeros((n, 7))
    h = P.T_i / P.n_sub
    r = P.lead / (2.0 * math.pi)  # table metres per screw radian
    th_m = x0 / r
    th_s = th_m
    w_m = 0.0
    w_s = 0.0
    x_t = x0 + P.lead_A * math.sin(th_s + P.lead_phase)
    v_t = 0.0
    i_d = 0.0
    i_q = 0.0
    dT = 0.0
    u_d_next = 0.0
    u_q_next = 0.0
    int_d = 0.0
    int_q = 0.0
    int_v = 0.0
    iq_ref = 0.0
    v_p = 0.0
    v_cmd = 0.0
    x_prev = x0
    nd = int(P.delay_periods)
    hist = np.full(nd + 1, x0)
    decay = math.exp(-P.R_s * h / P.L_s)
    count_m = 2.0 * math.pi / P.counts
    for k in range(n):
        t = k * P.T_i
        th_e = P.p * th_m
        c, s = math.cos(th_e), math.sin(th_e)
        # quantised motor encoder in table metres, seen by the loops nd periods late
        x_enc = math.floor(th_m / count_m) * count_m * r
        hist[k % (nd + 1)] = x_enc
        x_fb = hist[(k + 1) % (nd + 1)] if k >= nd else x0
        n_vel = int(P.n_vel)
        if k % n_vel == 0:
            if (k // n_vel) % int(P.n_pos) == 0:
                v_p = P.Kv * (x_ref[k] - x_fb)
            # the speed feed-forward is fine-interpolated at the velocity-loop rate: held over
            # a position period it would step, and the current kick at each step
            v_cmd = v_p + P.vff * v_ref[k]
            v_est = (x_fb - x_prev) / (P.T_i * P.n_vel) if k > 0 else 0.0
            x_prev = x_fb
            e_v = v_cmd - v_est
            raw = P.Kp_v * e_v + int_v
            if abs(raw) < P.i_max:
                int_v += P.Ki_v * e_v * P.T_i * P.n_vel
            iq_ref = min(max(raw, -P.i_max), P.i_max)
        # measured phase currents (true + sensor offsets) back into the rotor frame
        i_a = c * i_d - s * i_q + P.off_a
        i_b = math.cos(th_e - TWO_PI_3) * i_d - math.sin(th_e - TWO_PI_3) * i_q + P.off_b
        i_c = math.cos(th_e + TWO_PI_3) * i_d - math.sin(th_e + TWO_PI_3) * i_q + P.off_c
        ca, cb, cc = c, math.cos(th_e - TWO_PI_3), math.cos(th_e + TWO_PI_3)
        sa, sb, sc = s, math.sin(th_e - TWO_PI_3), math.sin(th_e + TWO_PI_3)
        id_meas = 2.0 / 3.0 * (ca * i_a + cb * i_b + cc * i_c)
        iq_meas = -2.0 / 3.0 * (sa * i_a + sb * i_b + sc * i_c)
        # this period runs on the voltage computed last period
        u_d, u_q = u_d_next, u_q_next
        e_d, e_q = 0.0 - id_meas, iq_ref - iq_meas
        u_lim = P.u_dc / math.sqrt(3.0)
        raw_d = P.Kp_i * e_d + int_d
        raw_q = P.Kp_i * e_q + int_q
        if abs(raw_d) < u_lim:
            int_d += P.Ki_i * e_d * P.T_i
        if abs(raw_q) < u_lim:
            int_q += P.Ki_i * e_q * P.T_i
        u_d_next = min(max(raw_d, -u_lim), u_lim)
        u_q_next = min(max(raw_q, -u_lim), u_lim)
        # dead time: each phase loses dead_volts against its current, seen in the rotor frame
        if P.dead_volts > 0.0:
            ua = -P.dead_volts * math.tanh(i_a / 0.05)
            ub = -P.dead_volts * math.tanh(i_b / 0.05)
            uc = -P.dead_volts * math.tanh(i_c / 0.05)
            u_d += 2.0 / 3.0 * (ca * ua + cb * ub + cc * uc)
            u_q += -2.0 / 3.0 * (sa * ua + sb * ub + sc * uc)
        f_fric = 0.0
        for _ in range(int(P.n_sub)):
            w_e = P.p * w_m
            # R-L windings: exact over h with back-EMF and cross coupling held
            fd = (u_d + w_e * P.L_s * i_q) / P.R_s
            fq = (u_q - w_e * (P.L_s * i_d + P.psi)) / P.R_s
            i_d = fd + (i_d - fd) * decay
            i_q = fq + (i_q - fq) * decay
            tau_e = 1.5 * P.p * P.psi * i_q
            tau_cog = P.cog_A * math.sin(P.cog_n * th_m + P.cog_phase)
            tau_c = P.k_c * (th_m - th_s) + P.d_c * (w_m - w_s)
            e_lead = P.lead_A * math.sin(th_s + P.lead_phase)
            x_nut = th_s * r + e_lead + P.alpha * dT * (P.x_0 + x_t)
            v_nut = w_s * r * (1.0 + P.lead_A / r * math.cos(th_s + P.lead_phase))
            f_ax = _axial_force(P, x_nut, x_t, v_nut, v_t)
            w_m += h * (tau_e - tau_cog - tau_c - P.b_m * w_m) / P.J_m
            w_s += h * (tau_c - f_ax * r) / P.J_s
            f_app = f_ax + P.F_const
            if P.F_hold > 0.0 and abs(v_t) < V_STICK and abs(f_app) <= P.F_hold:
                v_t = 0.0
                f_fric = f_app
            else:
                f_fric = _sliding_friction(P, v_t, t)
                v_new = v_t + h * (f_app - f_fric) / P.m
                if P.F_hold > 0.0 and v_new * v_t < 0.0:
                    v_new = 0.0  # a Karnopp table stops at the reversal, then the test decides
                v_t = v_new
            th_m += h * w_m
            th_s += h * w_s
            x_t += h * v_t
            dT += h * (P.heating * abs(v_t) - dT / P.tau_th)
        out[k, 0] = x_t
        out[k, 1] = th_m * r
        out[k, 2] = iq_meas
        out[k, 3] = iq_ref
        out[k, 4] = u_q
        out[k, 5] = i_q
        out[k, 6] = f_fric
    return out
