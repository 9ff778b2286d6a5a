"""Discrete control blocks shared by the loops: PI anti-windup, biquad filters, velocity estimator.

Each block is split into a design function (plain Python, run once when the parameter vector is
built) and a numba update function on scalars: memory in, (output, next memory) out. Scalars keep
the compiled tick free of array reference counting (an atomic increment and decrement per array
argument of every non-scalar call, which cost more than the control laws themselves).

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

Velocity estimator from position samples q(k) at period T (its loop over the taps lives in
`cascade.cascade_tick`, the only function that touches the state arrays):
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


@njit(forceinline=True)
def pi_integrate(x_i: float, e: float, ki_T: float, u_unsat: float, u_sat: float) -> float:
    """Next integrator value under conditional integration (see module docstring)."""
    excess = u_unsat - u_sat
    if excess != 0.0 and excess * e > 0.0:
        return x_i
    return x_i + ki_T * e


@njit(forceinline=True)
def pi_update(
    x_i: float, e: float, kp: float, ki_T: float, u_ff: float, lo: float, hi: float
) -> tuple[float, float]:
    """One PI sample with clamping anti-windup: (clipped output, next integrator value)."""
    u = kp * e + x_i + u_ff
    u_sat = min(max(u, lo), hi)
    return u_sat, pi_integrate(x_i, e, ki_T, u, u_sat)


@njit(forceinline=True)
def biquad_update(
    b0: float, b1: float, b2: float, a1: float, a2: float, s1: float, s2: float, x: float
) -> tuple[float, float, float]:
    """One biquad sample: (output, next s1, next s2)."""
    y = b0 * x + s1
    return y, b1 * x - a1 * y + s2, b2 * x - a2 * y
