"""The stator voltage a drive applied, rebuilt from its voltage references, and the d-axis fit.

A drive scope records the current controller's voltage references (u_d*, u_q*) at the sample k
they are computed, in the rotor frame of the angle theta_k latched with the phase currents. The
stator gets something else, and the difference is the drive's own, known to it:
- computation delay: with `computation_delay` the reference of sample k is modulated over
  [t_{k+1}, t_{k+2}) (over [t_k, t_{k+1}) without), at the inverse-Park angle
  theta_k + a omega_e T_i (a: `angle_advance_periods`); at the middle of that period the rotor
  stands at theta_k + m omega_e T_i, m = 1.5 (0.5), so the stator sees the reference turned by
  (a - m) omega_e T_i: u_d gets (m - a) omega_e T_i u_q*, which at speed is omega_e^2 terms;
- dead time: the modulator adds u_comp clip(i_x(k) / band, -1, 1) per phase (the drive's
  compensation, on the currents latched at k), the inverter takes
  (u_dc t_dead f_pwm + u_f) sgn(i_x / i_reg) off (plant.inverter) at the currents that flow
  while it applies, here the latched d/q currents at the application angle.
So, in the rotor frame at the middle of the application period,
    u_s = Park(theta_m) [InvPark(theta_k + a omega_e T_i) u* + Clarke(comp(i_abc(k)))
                         - Clarke(loss(i_abc at theta_m))],   theta_m = theta_k + m omega_e T_i,
and the d-axis equation u_d = R_s i_d + L_d di_d/dt - omega_e L_q i_q holds for u_s,d over the
application period, with the currents averaged over it and di_d/dt their change across it.

Why both are needed: the drive's compensation has the shape of its own law (linear to `band`)
and the inverter its own (the quintic smooth sign of i_reg); at the 0.1-0.5 A a feed axis draws
while cruising the two differ by up to a volt, as much as omega_e L_q i_q itself. Fitted at
every current-loop sample of the default twin, u_s gives L_q within 1.5 % at both jerk filters
(tests/test_stator_voltage.py); the references themselves read mostly the controller's own
decoupling gain L_q_H plus what its d integrator learned of these errors. Sampled once per
exchange (the node set's AxisFeedback, 1 kHz), always at the current loop's first sample after
the setpoint's step, the fit misses L_d di_d/dt of that sample and no reconstruction recovers it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feed_twin.core.arrays import FloatArray
from feed_twin.core.smooth import smooth_sign_array
from feed_twin.core.validate import require_nonnegative, require_positive, require_range

SQRT3_2 = 0.5 * np.sqrt(3.0)


@dataclass(frozen=True, kw_only=True)
class DriveVoltagePath:
    """What stands between a drive's voltage references and its motor's terminals."""

    T_i: float  # current-loop period [s]
    computation_delay: bool  # the reference of sample k applies from sample k+1
    angle_advance_periods: float  # the drive's delay compensation [current periods]
    dead_time_comp_V: float  # the drive's dead-time compensation per phase [V]
    dead_time_comp_band_A: float  # current over which the compensation changes sign [A]
    t_dead: float  # the inverter's interlock time [s]
    f_pwm: float  # PWM frequency [Hz]
    u_f: float  # conduction drop [V]
    i_reg: float  # current over which the inverter's error changes sign [A]

    def __post_init__(self) -> None:
        require_positive("T_i", self.T_i)
        require_range("angle_advance_periods", self.angle_advance_periods, 0.0, 3.0)
        require_nonnegative("dead_time_comp_V", self.dead_time_comp_V)
        require_positive("dead_time_comp_band_A", self.dead_time_comp_band_A)
        require_nonnegative("t_dead", self.t_dead)
        require_positive("f_pwm", self.f_pwm)
        require_nonnegative("u_f", self.u_f)
        require_positive("i_reg", self.i_reg)

    @property
    def application_periods(self) -> float:
        """m: the middle of the period the reference applies over, in current periods after
        the sample that computed it."""
        return 1.5 if self.computation_delay else 0.5


def _rotate(angle: FloatArray, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    c, s = np.cos(angle), np.sin(angle)
    return c * x - s * y, s * x + c * y


def applied_stator_voltage(
    path: DriveVoltagePath,
    *,
    u_d_ref: FloatArray,
    u_q_ref: FloatArray,
    theta_e: FloatArray,
    omega_e: FloatArray,
    i_a: FloatArray,
    i_b: FloatArray,
    i_c: FloatArray,
    u_dc: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """(u_d, u_q) [V] the stator got over the period each reference applied, in the rotor frame
    at that period's middle; theta_e [rad], omega_e [rad/s], the phase currents i_a, i_b, i_c
    [A] as latched with the reference, u_dc [V] the bus then."""
    omega_t = omega_e * path.T_i
    turn = path.application_periods * omega_t
    theta_m = theta_e + turn
    alpha, beta = _rotate(theta_e + path.angle_advance_periods * omega_t, u_d_ref, u_q_ref)
    band = path.dead_time_comp_band_A
    comp_a, comp_b, comp_c = (
        path.dead_time_comp_V * np.clip(i / band, -1.0, 1.0) for i in (i_a, i_b, i_c)
    )
    alpha = alpha + (2.0 * comp_a - comp_b - comp_c) / 3.0
    beta = beta + (comp_b - comp_c) / np.sqrt(3.0)
    # the currents that flow while it applies: the latched vector, turned with the rotor
    i_alpha, i_beta = _rotate(turn, (2.0 * i_a - i_b - i_c) / 3.0, (i_b - i_c) / np.sqrt(3.0))
    drop = u_dc * path.t_dead * path.f_pwm + path.u_f
    loss_a = drop * smooth_sign_array(i_alpha, path.i_reg)
    loss_b = drop * smooth_sign_array(-0.5 * i_alpha + SQRT3_2 * i_beta, path.i_reg)
    loss_c = drop * smooth_sign_array(-0.5 * i_alpha - SQRT3_2 * i_beta, path.i_reg)
    alpha = alpha - (2.0 * loss_a - loss_b - loss_c) / 3.0
    beta = beta - (loss_b - loss_c) / np.sqrt(3.0)
    return _rotate(-theta_m, alpha, beta)


@dataclass(frozen=True, kw_only=True)
class DAxisFit:
    """Least squares of u_d = R_s i_d + L_d di_d/dt - omega_e L_q i_q + c."""

    R_s: float  # [ohm]
    L_d: float  # [H]
    L_q: float  # [H]
    offset_V: float  # [V]


def d_axis_fit(
    u_d: FloatArray, i_d: FloatArray, i_q: FloatArray, omega_e: FloatArray, T_i: float
) -> DAxisFit:
    """The d-axis equation fitted at consecutive current-loop samples: u_d[k] (from
    `applied_stator_voltage`) applies over [t_{k+1}, t_{k+2}), against the currents averaged
    there and their change across it, the speed at its start."""
    if not len(u_d) == len(i_d) == len(i_q) == len(omega_e) >= 6:
        raise ValueError(
            f"d_axis_fit: {len(u_d)}, {len(i_d)}, {len(i_q)}, {len(omega_e)} samples of "
            f"u_d, i_d, i_q, omega_e: needs as many of each, at least 6"
        )
    n = len(u_d) - 2
    i_d_mean = 0.5 * (i_d[1 : n + 1] + i_d[2:])
    i_q_mean = 0.5 * (i_q[1 : n + 1] + i_q[2:])
    di_d = (i_d[2:] - i_d[1 : n + 1]) / T_i
    columns = np.c_[i_d_mean, di_d, -omega_e[1 : n + 1] * i_q_mean, np.ones(n)]
    (r_s, l_d, l_q, offset), *_ = np.linalg.lstsq(columns, u_d[:n], rcond=None)
    return DAxisFit(R_s=float(r_s), L_d=float(l_d), L_q=float(l_q), offset_V=float(offset))
