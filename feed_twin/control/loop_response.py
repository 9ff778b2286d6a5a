"""Linearised drive loops as transfer functions, and their margins and bandwidths.

A loop is a function s (complex array) -> L(s): PI controllers, the current loop's plant with
its dead time, the velocity loop's forward path, series and feedback connections, the position
open loop.

Margins come from the frequency response of the linearised open loop L(j w) on a logarithmic
grid, refined with Brent's method: phase margin 180 deg + arg L at |L| = 1, gain margin
-20 log10 |L| where arg L first reaches -180 deg.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np

# scipy ships no stubs: brentq is typed here, once
from scipy.optimize import brentq  # pyright: ignore[reportMissingTypeStubs, reportUnknownVariableType]

EPS = float(np.finfo(float).eps)

TWO_PI = 2.0 * math.pi
TransferFunction = Callable[[np.ndarray], np.ndarray]  # s (complex array) -> L(s)


@dataclass(frozen=True, kw_only=True)
class Margins:
    phase_margin_deg: float  # [deg]; inf when |L| never crosses 1
    crossover_rad_s: float  # gain crossover [rad/s]; nan when none
    gain_margin_db: float  # [dB]; inf when the phase never reaches -180 deg
    phase_crossover_rad_s: float  # [rad/s]; nan when none


def frequency_response(loop: TransferFunction, omega: np.ndarray) -> np.ndarray:
    """L(j w) at the angular frequencies omega [rad/s]."""
    return np.asarray(loop(1j * np.asarray(omega, dtype=np.float64)), dtype=np.complex128)


def unity(s: np.ndarray) -> np.ndarray:
    """The transfer function 1 (an absent stage), at every s."""
    return 1.0 + 0.0 * s


def loop_margins(
    loop: TransferFunction, *, omega_min: float = 1e-1, omega_max: float = 1e6, points: int = 4000
) -> Margins:
    """Phase and gain margins of the open loop `loop` (first crossings from low frequency)."""
    omega = np.geomspace(omega_min, omega_max, points)
    response = frequency_response(loop, omega)
    log_mag = np.log(np.abs(response))
    phase = np.unwrap(np.angle(response))
    crossover, pm = math.nan, math.inf
    down = np.nonzero((log_mag[:-1] >= 0.0) & (log_mag[1:] < 0.0))[0]
    if down.size:
        i = down[0]
        w_i, phase_i = float(omega[i]), float(phase[i])
        crossover = find_root(
            lambda w: math.log(abs(complex(loop(np.array([1j * w]))[0]))), w_i, float(omega[i + 1])
        )
        pm = 180.0 + math.degrees(_phase_at(loop, crossover, w_i, phase_i))
    phase_crossover, gm = math.nan, math.inf
    below = np.nonzero((phase[:-1] > -math.pi) & (phase[1:] <= -math.pi))[0]
    if below.size:
        i = below[0]
        w_i, phase_i = float(omega[i]), float(phase[i])
        phase_crossover = find_root(
            lambda w: _phase_at(loop, w, w_i, phase_i) + math.pi, w_i, float(omega[i + 1])
        )
        gm = -20.0 * math.log10(abs(complex(loop(np.array([1j * phase_crossover]))[0])))
    return Margins(
        phase_margin_deg=pm,
        crossover_rad_s=crossover,
        gain_margin_db=gm,
        phase_crossover_rad_s=phase_crossover,
    )


def find_root(f: Callable[[float], float], lo: float, hi: float, *, rtol: float = 4 * EPS) -> float:
    """The root of f in [lo, hi] by Brent's method (scipy's brentq, its default tolerances)."""
    root = cast(float, brentq(f, lo, hi, rtol=np.float64(rtol)))  # a float: no full_output
    return float(root)


def _phase_at(loop: TransferFunction, w: float, w_ref: float, phase_ref: float) -> float:
    """Continuous phase at w, on the branch of the unwrapped phase at the nearby w_ref."""
    ratio = complex(loop(np.array([1j * w]))[0]) / complex(loop(np.array([1j * w_ref]))[0])
    return phase_ref + math.atan2(ratio.imag, ratio.real)


def closed_loop_bandwidth(
    closed_loop: TransferFunction, *, omega_min: float = 1e-1, omega_max: float = 1e6
) -> float:
    """-3 dB frequency [rad/s] of a closed loop T(s) with T(0) = 1 (first crossing of 1/sqrt 2)."""
    omega = np.geomspace(omega_min, omega_max, 4000)
    mag = np.abs(frequency_response(closed_loop, omega))
    target = 1.0 / math.sqrt(2.0)
    idx = np.nonzero((mag[:-1] >= target) & (mag[1:] < target))[0]
    if not idx.size:
        return math.nan
    i = idx[0]
    return find_root(
        lambda w: abs(complex(closed_loop(np.array([1j * w]))[0])) - target,
        float(omega[i]),
        float(omega[i + 1]),
    )


# Linearised loops


def pi_controller(Kp: float, Ti_s: float | None) -> TransferFunction:
    """C(s) = Kp (1 + 1/(s Ti)); P only when Ti is None."""
    if Ti_s is None:
        return lambda s: Kp + 0.0 * s
    return lambda s: Kp * (1.0 + 1.0 / (s * Ti_s))


def current_open_loop(
    *, Kp: float, Ti_s: float, R_s: float, L: float, T_sigma_s: float
) -> TransferFunction:
    """L_i(s) = PI(s) e^{-s T_sigma} / (R_s + s L)."""
    pi = pi_controller(Kp, Ti_s)
    return lambda s: pi(s) * np.exp(-s * T_sigma_s) / (R_s + s * L)


def dead_time(T_s: float) -> TransferFunction:
    return lambda s: np.exp(-s * T_s)


def velocity_forward(
    *,
    Kp: float,
    Ti_s: float | None,
    m_eq_kg: float,
    force_per_unit: float,
    T_hold_s: float,
    current_closed_loop: TransferFunction | None,
) -> TransferFunction:
    """Forward path PI(s) G_ci(s) F/(m s) e^{-s T_hold} from velocity error to true velocity,
    load side; the estimator delay belongs to the feedback path (see `closed`)."""
    pi = pi_controller(Kp, Ti_s)
    inner = current_closed_loop or unity
    return lambda s: pi(s) * inner(s) * force_per_unit / (m_eq_kg * s) * np.exp(-s * T_hold_s)


def series(*parts: TransferFunction) -> TransferFunction:
    def product(s: np.ndarray) -> np.ndarray:
        result = np.ones_like(s)
        for part in parts:
            result = result * part(s)
        return result

    return product


def closed(forward: TransferFunction, feedback: TransferFunction | None = None) -> TransferFunction:
    """Setpoint to output: F/(1 + F H); the output is the true one, before the sensor path H."""
    if feedback is None:
        return lambda s: forward(s) / (1.0 + forward(s))
    return lambda s: forward(s) / (1.0 + forward(s) * feedback(s))


def position_open_loop(
    *, Kv_1_s: float, velocity_closed_loop: TransferFunction, T_delay_s: float
) -> TransferFunction:
    """L_p(s) = Kv/s * T_v(s) e^{-s T_delay}."""
    return lambda s: Kv_1_s / s * velocity_closed_loop(s) * np.exp(-s * T_delay_s)
