"""Discrete control blocks shared by the loops: PI anti-windup, biquad filters, velocity estimator.

Each block is split into a design function (plain Python, run once when the parameter vector is
built) and a numba step kernel that reads its coefficients from the parameter vector `cp` and its
memory from the state vector `cs` at given offsets, so the compiled loop has no objects.

PI with anti-windup by conditional integration (clamping):
    u = Kp*e + x_i + u_ff,  u_sat = clip(u, lo, hi),
    x_i(k+1) = x_i(k) + Ki*T*e  unless the output is clipped and e pushes further into the clip.
The integrator therefore stops growing the instant the output saturates and resumes as soon as
the error changes sign, which bounds the overshoot after saturation (no back-calculation gain to
tune).

Biquad (transposed direct form II), coefficients normalised to a0 = 1:
    y = b0*x + s1,  s1 <- b1*x - a1*y + s2,  s2 <- b2*x - a2*y.
Designs use the bilinear transform pre-warped at the characteristic frequency, so the notch
depth and the low-pass -3 dB point hold exactly at that frequency after discretisation:
    notch   H(s) = (s^2 + 2*depth*zeta*w0*s + w0^2) / (s^2 + 2*zeta*w0*s + w0^2),
            zeta = bandwidth / (2*f0), |H(j*w0)| = depth;
    lowpass H(s) = w0^2 / (s^2 + (w0/Q)*s + w0^2).

Velocity estimator from position samples q(k) at period T:
    v_raw(k) = sum_i c_i * (q(k-i) - q(k-i-1)) / T  (FIR on differences, sum c_i = 1),
then an optional first-order low-pass  v(k) = v(k-1) + alpha*(v_raw(k) - v(k-1)),
alpha = 1 - exp(-2*pi*f_c*T). With sum c_i = 1 the FIR estimate is exact on a ramp once its
memory is full.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

BIQUAD_COEFFS = 5  # b0, b1, b2, a1, a2
BIQUAD_STATES = 2  # s1, s2
BIQUAD_IDENTITY = (1.0, 0.0, 0.0, 0.0, 0.0)


def _bilinear(num: tuple[float, float, float], den: tuple[float, float, float], K: float):
    """Map H(s) = (n2 s^2 + n1 s + n0)/(d2 s^2 + d1 s + d0) with s = K (z-1)/(z+1)."""
    n2, n1, n0 = num
    d2, d1, d0 = den
    b = np.array([n2 * K * K + n1 * K + n0, 2.0 * (n0 - n2 * K * K), n2 * K * K - n1 * K + n0])
    a = np.array([d2 * K * K + d1 * K + d0, 2.0 * (d0 - d2 * K * K), d2 * K * K - d1 * K + d0])
    return (b[0] / a[0], b[1] / a[0], b[2] / a[0], a[1] / a[0], a[2] / a[0])


def _prewarp(frequency_hz: float, period_s: float) -> tuple[float, float]:
    nyquist = 0.5 / period_s
    if not 0.0 < frequency_hz < nyquist:
        raise ValueError(
            f"frequency {frequency_hz!r} Hz must lie in (0, {nyquist!r}) Hz (Nyquist at T = "
            f"{period_s!r} s)"
        )
    w0 = 2.0 * math.pi * frequency_hz
    return w0, w0 / math.tan(0.5 * w0 * period_s)


def notch_coefficients(
    *, frequency_hz: float, bandwidth_hz: float, depth: float, period_s: float
) -> tuple[float, float, float, float, float]:
    """Discrete notch with gain `depth` at `frequency_hz` and -3 dB-ish width `bandwidth_hz`."""
    w0, K = _prewarp(frequency_hz, period_s)
    zeta = bandwidth_hz / (2.0 * frequency_hz)
    return _bilinear((1.0, 2.0 * depth * zeta * w0, w0 * w0), (1.0, 2.0 * zeta * w0, w0 * w0), K)


def lowpass2_coefficients(
    *, frequency_hz: float, period_s: float, Q: float = 1.0 / math.sqrt(2.0)
) -> tuple[float, float, float, float, float]:
    """Discrete second-order low-pass (Butterworth for the default Q) with unit DC gain."""
    w0, K = _prewarp(frequency_hz, period_s)
    return _bilinear((0.0, 0.0, w0 * w0), (1.0, w0 / Q, w0 * w0), K)


def biquad_response(coeffs: tuple[float, ...], frequency_hz: float, period_s: float) -> complex:
    """Frequency response of a discrete biquad at `frequency_hz`."""
    b0, b1, b2, a1, a2 = coeffs
    z1 = np.exp(-2j * np.pi * frequency_hz * period_s)
    return complex((b0 + b1 * z1 + b2 * z1 * z1) / (1.0 + a1 * z1 + a2 * z1 * z1))


def lowpass1_alpha(frequency_hz: float, period_s: float) -> float:
    """Smoothing factor of a first-order low-pass with corner `frequency_hz` (exact pole map)."""
    return 1.0 - math.exp(-2.0 * math.pi * frequency_hz * period_s)


@njit(cache=True)
def pi_integrate(x_i: float, e: float, ki_T: float, u_unsat: float, u_sat: float) -> float:
    """Next integrator value under conditional integration (see module docstring)."""
    excess = u_unsat - u_sat
    if excess != 0.0 and excess * e > 0.0:
        return x_i
    return x_i + ki_T * e


@njit(cache=True)
def pi_step(
    cs: np.ndarray, i_int: int, e: float, kp: float, ki_T: float, u_ff: float, lo: float, hi: float
) -> float:
    """One PI sample with clamping anti-windup; integrator in cs[i_int]. Returns clipped output."""
    u = kp * e + cs[i_int] + u_ff
    u_sat = min(max(u, lo), hi)
    cs[i_int] = pi_integrate(cs[i_int], e, ki_T, u, u_sat)
    return u_sat


@njit(cache=True)
def biquad_step(cp: np.ndarray, i_coef: int, cs: np.ndarray, i_state: int, x: float) -> float:
    """One sample of the biquad whose coefficients start at cp[i_coef], states at cs[i_state]."""
    y = cp[i_coef] * x + cs[i_state]
    cs[i_state] = cp[i_coef + 1] * x - cp[i_coef + 3] * y + cs[i_state + 1]
    cs[i_state + 1] = cp[i_coef + 2] * x - cp[i_coef + 4] * y
    return y


@njit(cache=True)
def fir_velocity_step(
    cp: np.ndarray,
    i_taps: int,
    n_taps: int,
    cs: np.ndarray,
    i_hist: int,
    i_prev: int,
    q: float,
    period_s: float,
) -> float:
    """FIR velocity estimate from a new position sample q; history of differences in cs."""
    for i in range(n_taps - 1, 0, -1):
        cs[i_hist + i] = cs[i_hist + i - 1]
    cs[i_hist] = (q - cs[i_prev]) / period_s
    cs[i_prev] = q
    v = 0.0
    for i in range(n_taps):
        v += cp[i_taps + i] * cs[i_hist + i]
    return v
