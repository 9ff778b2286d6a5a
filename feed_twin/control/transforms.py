"""Reference-frame transforms and space-vector modulation for field-oriented control.

All transforms are amplitude invariant (the convention of most drive firmware): a balanced
three-phase set of peak amplitude I maps to a space vector of length I, so `i_q` is a phase-current
amplitude and the torque of a PMSM is `1.5 * p * (psi_pm * i_q + (L_d - L_q) * i_d * i_q)`.
The power in the alpha/beta (or d/q) frame is therefore `P = 1.5 * (u_alpha*i_alpha +
u_beta*i_beta)`: `POWER_FACTOR_AMPLITUDE_INVARIANT` is that 1.5.

Clarke  (a, b, c -> alpha, beta):
    x_alpha = (2/3) * (x_a - x_b/2 - x_c/2),  x_beta = (x_b - x_c) / sqrt(3)
Park    (alpha, beta -> d, q at electrical angle theta_e):
    x_d = cos(theta_e)*x_alpha + sin(theta_e)*x_beta
    x_q = -sin(theta_e)*x_alpha + cos(theta_e)*x_beta
SVPWM   (min-max zero-sequence injection): the phase references
    u_x* = u_x + u_0,  u_0 = -(max(u_a, u_b, u_c) + min(u_a, u_b, u_c)) / 2
and duty cycles `d_x = 1/2 + u_x*/u_dc` in [0, 1]. An averaged inverter then produces the
line-to-line voltages `u_xy = (d_x - d_y) * u_dc` = the requested ones while `|u| <= u_dc/sqrt(3)`
(the linear range, 15.5 % above sine-triangle PWM's u_dc/2).

Every function is a numba kernel callable from Python and from the compiled engine loop.
"""

from __future__ import annotations

import math

from numba import njit

SQRT3 = math.sqrt(3.0)
INV_SQRT3 = 1.0 / SQRT3
POWER_FACTOR_AMPLITUDE_INVARIANT = 1.5


@njit(forceinline=True)
def clarke(x_a: float, x_b: float, x_c: float) -> tuple[float, float]:
    """Phase quantities -> (alpha, beta); any zero-sequence part is discarded."""
    return (2.0 / 3.0) * (x_a - 0.5 * x_b - 0.5 * x_c), (x_b - x_c) * INV_SQRT3


@njit(forceinline=True)
def inverse_clarke(x_alpha: float, x_beta: float) -> tuple[float, float, float]:
    """(alpha, beta) -> phase quantities without zero-sequence part."""
    x_a = x_alpha
    x_b = -0.5 * x_alpha + 0.5 * SQRT3 * x_beta
    x_c = -0.5 * x_alpha - 0.5 * SQRT3 * x_beta
    return x_a, x_b, x_c


@njit(forceinline=True)
def park(x_alpha: float, x_beta: float, theta_e: float) -> tuple[float, float]:
    """(alpha, beta) -> (d, q) in the frame at electrical angle theta_e [rad]."""
    c = math.cos(theta_e)
    s = math.sin(theta_e)
    return c * x_alpha + s * x_beta, -s * x_alpha + c * x_beta


@njit(forceinline=True)
def inverse_park(x_d: float, x_q: float, theta_e: float) -> tuple[float, float]:
    """(d, q) at electrical angle theta_e [rad] -> (alpha, beta)."""
    c = math.cos(theta_e)
    s = math.sin(theta_e)
    return c * x_d - s * x_q, s * x_d + c * x_q


@njit(forceinline=True)
def limit_voltage_circle(u_d: float, u_q: float, u_max: float) -> tuple[float, float]:
    """Limit (u_d, u_q) to the circle of radius u_max with d-axis priority.

    The d axis keeps its demand (up to u_max) because it carries the decoupling voltage that keeps
    the current vector under control; the q axis gets what remains of the circle.
    """
    u_d_lim = min(max(u_d, -u_max), u_max)
    room2 = u_max * u_max - u_d_lim * u_d_lim
    if u_q * u_q <= room2:
        return u_d_lim, u_q  # inside the circle: no root on the usual path
    u_q_room = math.sqrt(max(room2, 0.0))
    u_q_lim = min(max(u_q, -u_q_room), u_q_room)
    return u_d_lim, u_q_lim


@njit(forceinline=True)
def svpwm_phase_duties(
    u_a: float, u_b: float, u_c: float, u_dc: float
) -> tuple[float, float, float]:
    """Duty cycles in [0, 1] for phase voltage references [V] (any common mode is replaced).

    Min-max zero-sequence injection; outside the linear range the duties clip at 0/1 and the
    inverter saturates (overmodulation), which the voltage-circle limit upstream normally prevents.
    """
    u_0 = -0.5 * (max(u_a, max(u_b, u_c)) + min(u_a, min(u_b, u_c)))
    inv = 1.0 / u_dc
    d_a = min(max(0.5 + (u_a + u_0) * inv, 0.0), 1.0)
    d_b = min(max(0.5 + (u_b + u_0) * inv, 0.0), 1.0)
    d_c = min(max(0.5 + (u_c + u_0) * inv, 0.0), 1.0)
    return d_a, d_b, d_c


@njit(forceinline=True)
def modulate(
    u_d: float,
    u_q: float,
    cos_e: float,
    sin_e: float,
    i_a: float,
    i_b: float,
    i_c: float,
    dead_time_comp_V: float,
    dead_time_comp_band_A: float,
    u_dc: float,
) -> tuple[float, float, float]:
    """The modulator: (u_d, u_q) [V] at the angle whose (cos, sin) is given -> duty cycles.

    Inverse Park, then per phase the dead-time compensation u_comp * clip(i_x / band, -1, 1)
    (the inverter's dead time takes about u_comp off a phase in the direction of its current),
    then SVPWM on u_dc; a bus without voltage gets duties 1/2. The cascade's current loop and
    the node set's voltage-mode drive both modulate with it.
    """
    if u_dc <= 0.0:
        return 0.5, 0.5, 0.5
    u_a, u_b, u_c = inverse_clarke(cos_e * u_d - sin_e * u_q, sin_e * u_d + cos_e * u_q)
    if dead_time_comp_V > 0.0:
        inv_band = 1.0 / dead_time_comp_band_A
        u_a += dead_time_comp_V * min(max(i_a * inv_band, -1.0), 1.0)
        u_b += dead_time_comp_V * min(max(i_b * inv_band, -1.0), 1.0)
        u_c += dead_time_comp_V * min(max(i_c * inv_band, -1.0), 1.0)
    return svpwm_phase_duties(u_a, u_b, u_c, u_dc)


@njit(forceinline=True)
def svpwm_duties(u_alpha: float, u_beta: float, u_dc: float) -> tuple[float, float, float]:
    """Duty cycles in [0, 1] for a two-level inverter from the (alpha, beta) voltage [V]."""
    u_a, u_b, u_c = inverse_clarke(u_alpha, u_beta)
    return svpwm_phase_duties(u_a, u_b, u_c, u_dc)
