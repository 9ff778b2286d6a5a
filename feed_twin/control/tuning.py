"""Controller tuning from plant parameters, and margins of the linearised loops.

Delays are lumped into a dead time T_sigma per loop (computation delay plus zero-order hold plus
measurement delay); the loops are linearised with L_d = L_q, no friction, rigid mechanics.

Current loop, plant 1/(R_s + s L) e^{-s T_sigma}, T_sigma = 1.5 * T_i (one sample computation
delay + half a sample of zero-order hold). PI with Ti = L/R_s cancels the electrical pole:
    technical optimum (Betragsoptimum):  Kp = L / (2 T_sigma)
    given bandwidth f_c:                 Kp = 2 pi f_c L   (open-loop crossover at 2 pi f_c)
Velocity loop, plant K_t/(J s) behind the closed current loop G_ci(s), with
    T_sigma_v = 2 T_sigma_i (current loop as lag) + T_v (hold + difference quotient) + FIR group
                delay + 1/(2 pi f_lp) (estimator low-pass),
symmetric optimum with the normalised crossover a (a = 2: 36.9 deg phase margin):
    Kp = J / (K_t a T_sigma_v)  [A per rad/s],  Ti = a^2 T_sigma_v,  crossover 1/(a T_sigma_v);
the load-side gain is Kp * 2 pi / lead [A per m/s].
Position loop: the Kv that gives a target phase margin (default 70 deg) around the closed
velocity loop, and, closed on a linear scale, at most 2 zeta w0 / 2 of the load's first mode
(the mode's resonance peak 1/(2 zeta) must not lift |L| to 1 at -180 deg).

The loops, their margins and bandwidths are in feed_twin.control.loop_response.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feed_twin.control.config import ControllerConfig
from feed_twin.control.loop_response import (
    TWO_PI,
    Margins,
    TransferFunction,
    closed,
    closed_loop_bandwidth,
    current_open_loop,
    dead_time,
    find_root,
    loop_margins,
    position_open_loop,
    series,
    unity,
    velocity_forward,
)

# Designs


@dataclass(frozen=True, kw_only=True)
class CurrentLoopDesign:
    Kp_V_A: float
    Ti_s: float
    T_sigma_s: float  # lumped dead time [s]
    rise_time_90_s: float  # time to 90 % of a current step, linear model [s]
    bandwidth_hz: float  # closed-loop -3 dB [Hz]
    margins: Margins


def current_rise_time_90(
    *, Kp: float, Ti_s: float, R_s: float, L: float, T_sigma_s: float, steps_per_delay: int = 400
) -> float:
    """Time for the linearised current loop to reach 90 % of a step (fine-step simulation)."""
    dt = T_sigma_s / steps_per_delay
    buffer = np.zeros(steps_per_delay)
    i = 0.0
    integral = 0.0
    for n in range(200 * steps_per_delay):
        e = 1.0 - i
        integral += Kp / Ti_s * e * dt
        u = buffer[n % steps_per_delay]
        buffer[n % steps_per_delay] = Kp * e + integral
        i += dt * (u - R_s * i) / L
        if i >= 0.9:
            return (n + 1) * dt
    return math.inf


def tune_current_loop(
    *,
    R_s: float,
    L: float,
    period_s: float,
    delay_periods: float = 1.5,
    bandwidth_hz: float | None = None,
) -> CurrentLoopDesign:
    """PI gains for the current loop: technical optimum, or a given crossover frequency."""
    for name, value in (("R_s", R_s), ("L", L), ("period_s", period_s)):
        if not value > 0.0:
            raise ValueError(f"{name} = {value!r}: must be > 0")
    T_sigma = delay_periods * period_s
    Ti = L / R_s
    Kp = L / (2.0 * T_sigma) if bandwidth_hz is None else TWO_PI * bandwidth_hz * L
    loop = current_open_loop(Kp=Kp, Ti_s=Ti, R_s=R_s, L=L, T_sigma_s=T_sigma)
    return CurrentLoopDesign(
        Kp_V_A=Kp,
        Ti_s=Ti,
        T_sigma_s=T_sigma,
        rise_time_90_s=current_rise_time_90(Kp=Kp, Ti_s=Ti, R_s=R_s, L=L, T_sigma_s=T_sigma),
        bandwidth_hz=closed_loop_bandwidth(closed(loop)) / TWO_PI,
        margins=loop_margins(loop),
    )


@dataclass(frozen=True, kw_only=True)
class VelocityLoopDesign:
    Kp: float  # [effort unit per m/s], load side
    Ti_s: float
    T_sigma_s: float  # lumped small time constants [s]
    a: float  # symmetric-optimum normalised crossover [-]
    crossover_hz: float  # design open-loop crossover 1/(2 pi a T_sigma) [Hz]
    bandwidth_hz: float  # closed-loop -3 dB of the linearised loop [Hz]
    margins: Margins


def estimator_delay(
    fir_taps: tuple[float, ...], lowpass_hz: float | None, period_s: float
) -> float:
    """Low-frequency delay of the velocity estimate [s]: half a sample for the difference
    quotient, the FIR's group delay sum(i c_i) T, and 1/(2 pi f) for the low-pass."""
    fir = sum(i * c for i, c in enumerate(fir_taps)) * period_s
    lp = 0.0 if lowpass_hz is None else 1.0 / (TWO_PI * lowpass_hz)
    return 0.5 * period_s + fir + lp


def tune_velocity_loop(
    *,
    J_total_kg_m2: float,
    K_t: float,
    lead_m: float,
    period_s: float,
    T_current_s: float,
    estimator_delay_s: float,
    a: float = 2.0,
    crossover_hz: float | None = None,
    current_closed_loop: TransferFunction | None = None,
) -> VelocityLoopDesign:
    """Symmetric optimum PI for the velocity loop (load-side gains).

    `T_current_s` is the equivalent lag of the closed current loop (2 T_sigma_i for the technical
    optimum, 0 for an ideal force source); `crossover_hz` overrides `a` with a target crossover.
    """
    for name, value in (
        ("J_total_kg_m2", J_total_kg_m2),
        ("K_t", K_t),
        ("lead_m", lead_m),
        ("period_s", period_s),
    ):
        if not value > 0.0:
            raise ValueError(f"{name} = {value!r}: must be > 0")
    for name, value in (("T_current_s", T_current_s), ("estimator_delay_s", estimator_delay_s)):
        if not value >= 0.0:
            raise ValueError(f"{name} = {value!r}: must be >= 0")
    T_sigma = T_current_s + 0.5 * period_s + estimator_delay_s
    if crossover_hz is not None:
        a = 1.0 / (TWO_PI * crossover_hz * T_sigma)
        if not a > 1.0:
            raise ValueError(
                f"crossover_hz = {crossover_hz!r}: too high for the loop's delays "
                f"(T_sigma = {T_sigma!r} s needs a crossover below {1 / (TWO_PI * T_sigma)!r} Hz)"
            )
    elif not a > 1.0:
        raise ValueError(f"a = {a!r}: must be > 1 (a = 2 is the classic symmetric optimum)")
    ratio = TWO_PI / lead_m  # motor rad per table m
    Kp_rad = J_total_kg_m2 / (K_t * a * T_sigma)
    Kp = Kp_rad * ratio
    Ti = a * a * T_sigma
    forward = velocity_forward(
        Kp=Kp,
        Ti_s=Ti,
        m_eq_kg=J_total_kg_m2 * ratio * ratio,
        force_per_unit=K_t * ratio,
        T_hold_s=0.5 * period_s,
        current_closed_loop=current_closed_loop or (lambda s: 1.0 / (1.0 + s * T_current_s)),
    )
    feedback = dead_time(estimator_delay_s)
    return VelocityLoopDesign(
        Kp=Kp,
        Ti_s=Ti,
        T_sigma_s=T_sigma,
        a=a,
        crossover_hz=1.0 / (TWO_PI * a * T_sigma),
        bandwidth_hz=closed_loop_bandwidth(closed(forward, feedback)) / TWO_PI,
        margins=loop_margins(series(forward, feedback)),
    )


@dataclass(frozen=True, kw_only=True)
class PositionLoopDesign:
    Kv_1_s: float
    limited_by: str  # "phase margin" or "load mode"
    margins: Margins


@dataclass(frozen=True, kw_only=True)
class LoadMode:
    """The first mode of the load against the motor, seen by a position loop on the scale."""

    frequency_hz: float  # undamped natural frequency [Hz]
    zeta: float  # modal damping ratio [-]

    def __post_init__(self) -> None:
        if not self.frequency_hz > 0.0:
            raise ValueError(f"frequency_hz = {self.frequency_hz!r}: must be > 0")
        if not 0.0 < self.zeta < 1.0:
            raise ValueError(f"zeta = {self.zeta!r}: must lie in (0, 1)")

    def transfer(self) -> TransferFunction:
        """Load position per motor-side position: w0^2 / (s^2 + 2 zeta w0 s + w0^2)."""
        w0 = TWO_PI * self.frequency_hz
        return lambda s: w0 * w0 / (s * s + 2.0 * self.zeta * w0 * s + w0 * w0)


def tune_position_loop(
    *,
    velocity_closed_loop: TransferFunction,
    velocity_bandwidth_hz: float,
    period_s: float,
    phase_margin_deg: float = 70.0,
    load_mode: LoadMode | None = None,
    mode_gain_margin: float = 2.0,
) -> PositionLoopDesign:
    """The Kv that gives the position loop around the closed velocity loop a target phase margin,
    and, closed on the load (linear scale), at most 2 zeta w0 / mode_gain_margin.

    The margin falls monotonically with Kv (more crossover frequency, more lag from the velocity
    loop and the delay), so Brent's method on Kv in (0, 2 pi f_bw,v] finds it; 70 deg keeps the
    setpoint response free of overshoot, as contouring requires. A lightly damped load mode at
    w0 raises |L| there by 1/(2 zeta) at -180 deg: |L(j w0)| = Kv / (2 zeta w0) must stay below 1.
    """
    if not 0.0 < phase_margin_deg < 90.0:
        raise ValueError(f"phase_margin_deg = {phase_margin_deg!r}: must lie in (0, 90)")
    if not mode_gain_margin >= 1.0:
        raise ValueError(f"mode_gain_margin = {mode_gain_margin!r}: must be >= 1")
    mode = load_mode.transfer() if load_mode is not None else unity

    def loop_for(Kv: float) -> TransferFunction:
        rigid = position_open_loop(
            Kv_1_s=Kv, velocity_closed_loop=velocity_closed_loop, T_delay_s=0.5 * period_s
        )
        return series(rigid, mode)

    def margin(Kv: float) -> float:
        return loop_margins(loop_for(Kv)).phase_margin_deg - phase_margin_deg

    Kv_max = TWO_PI * velocity_bandwidth_hz
    Kv = Kv_max if margin(Kv_max) >= 0.0 else find_root(margin, 1e-6 * Kv_max, Kv_max, rtol=1e-6)
    limited_by = "phase margin"
    if load_mode is not None:
        Kv_mode = 2.0 * load_mode.zeta * TWO_PI * load_mode.frequency_hz / mode_gain_margin
        if Kv_mode < Kv:
            Kv, limited_by = Kv_mode, "load mode"
    return PositionLoopDesign(Kv_1_s=Kv, limited_by=limited_by, margins=loop_margins(loop_for(Kv)))


# A whole configuration


@dataclass(frozen=True, kw_only=True)
class TuningReport:
    current_design: CurrentLoopDesign | None
    current_configured: Margins | None
    current_bandwidth_hz: float | None
    velocity_design: VelocityLoopDesign | None
    velocity_configured: Margins | None
    velocity_bandwidth_hz: float | None
    position_design: PositionLoopDesign | None
    position_configured: Margins | None
    # the gains of the config file, beside the margins they give
    configured_current: str = ""  # e.g. "Kp = 21.33 V/A, Ti = 0.01143 s"
    configured_velocity: str = ""
    configured_position: str = ""
    effort_per_m_s: str = "per m/s"  # the unit of the velocity loop's Kp

    def lines(self) -> list[str]:
        """Human-readable summary, one line per loop and variant."""
        out: list[str] = []

        def fmt(m: Margins | None) -> str:
            if m is None:
                return "-"
            return (
                f"PM {m.phase_margin_deg:6.1f} deg at {m.crossover_rad_s / TWO_PI:8.1f} Hz, "
                f"GM {m.gain_margin_db:5.1f} dB"
            )

        if self.current_design is not None:
            d = self.current_design
            out.append(
                f"current  design    Kp = {d.Kp_V_A:.4g} V/A, Ti = {d.Ti_s:.4g} s, "
                f"t90 = {d.rise_time_90_s * 1e6:.0f} us, bw = {d.bandwidth_hz:.0f} Hz; "
                + fmt(d.margins)
            )
            out.append(
                f"current  configured {self.configured_current}, "
                f"bw = {self.current_bandwidth_hz:.0f} Hz; " + fmt(self.current_configured)
            )
        if self.velocity_design is not None:
            d = self.velocity_design
            out.append(
                f"velocity design    Kp = {d.Kp:.4g} {self.effort_per_m_s}, Ti = {d.Ti_s:.4g} s, "
                f"a = {d.a:.2f}, "
                f"bw = {d.bandwidth_hz:.0f} Hz; " + fmt(d.margins)
            )
            out.append(
                f"velocity configured {self.configured_velocity}, "
                f"bw = {self.velocity_bandwidth_hz:.0f} Hz; " + fmt(self.velocity_configured)
            )
        if self.position_design is not None:
            out.append(
                f"position design    Kv = {self.position_design.Kv_1_s:.4g} 1/s "
                f"(limited by {self.position_design.limited_by}); "
                + fmt(self.position_design.margins)
            )
            out.append(
                f"position configured {self.configured_position}; " + fmt(self.position_configured)
            )
        return out


def tune_config(config: ControllerConfig, *, load_mode: LoadMode | None = None) -> TuningReport:
    """Recommended gains for a configuration's plant facts, and margins of its configured gains.

    `load_mode` (the first mode of the load against the motor) enters the position loop when it
    is closed on the linear scale; a semi-closed loop does not see it in its feedback.
    """
    drive = config.drive
    ratio = TWO_PI / drive.lead_m
    m_eq = drive.J_total_kg_m2 * ratio * ratio
    force_per_unit = drive.K_t * ratio
    cur, vel, pos = config.current, config.velocity, config.position
    cur_design = cur_conf = cur_bw = None
    inner_closed: TransferFunction | None = None
    T_current = 0.0
    if cur is not None:
        cur_design = tune_current_loop(R_s=cur.R_s_ohm, L=cur.L_q_H, period_s=cur.period_s)
        configured = current_open_loop(
            Kp=cur.Kp_q_V_A,
            Ti_s=cur.Ti_q_s,
            R_s=cur.R_s_ohm,
            L=cur.L_q_H,
            T_sigma_s=cur_design.T_sigma_s,
        )
        cur_conf = loop_margins(configured)
        cur_bw = closed_loop_bandwidth(closed(configured)) / TWO_PI
        inner_closed = closed(configured)
        T_current = 2.0 * cur_design.T_sigma_s
    vel_design = vel_conf = vel_bw = None
    pos_design = pos_conf = None
    if vel is not None:
        est_delay = estimator_delay(vel.estimator.fir_taps, vel.estimator.lowpass_hz, vel.period_s)
        vel_design = tune_velocity_loop(
            J_total_kg_m2=drive.J_total_kg_m2,
            K_t=drive.K_t,
            lead_m=drive.lead_m,
            period_s=vel.period_s,
            T_current_s=T_current,
            estimator_delay_s=est_delay,
            current_closed_loop=inner_closed,
        )
        forward = velocity_forward(
            Kp=vel.Kp,
            Ti_s=vel.Ti_s,
            m_eq_kg=m_eq,
            force_per_unit=force_per_unit,
            T_hold_s=0.5 * vel.period_s,
            current_closed_loop=inner_closed,
        )
        feedback = dead_time(est_delay)
        vel_conf = loop_margins(series(forward, feedback))
        velocity_closed = closed(forward, feedback)
        vel_bw = closed_loop_bandwidth(velocity_closed) / TWO_PI
        if pos is not None:
            seen = load_mode if pos.feedback == "linear_scale" else None
            pos_design = tune_position_loop(
                velocity_closed_loop=velocity_closed,
                velocity_bandwidth_hz=vel_bw,
                period_s=pos.period_s,
                load_mode=seen,
            )
            configured_p = position_open_loop(
                Kv_1_s=pos.Kv_1_s,
                velocity_closed_loop=velocity_closed,
                T_delay_s=0.5 * pos.period_s,
            )
            if seen is not None:
                configured_p = series(configured_p, seen.transfer())
            pos_conf = loop_margins(configured_p)
    return TuningReport(
        current_design=cur_design,
        current_configured=cur_conf,
        current_bandwidth_hz=cur_bw,
        velocity_design=vel_design,
        velocity_configured=vel_conf,
        velocity_bandwidth_hz=vel_bw,
        position_design=pos_design,
        position_configured=pos_conf,
        configured_current="" if cur is None else (
            f"Kp = {cur.Kp_q_V_A:.4g} V/A, Ti = {cur.Ti_q_s:.4g} s"
        ),
        configured_velocity="" if vel is None else (
            f"Kp = {vel.Kp:.4g} {_effort_per_m_s(cur is not None)}"
            + ("" if vel.Ti_s is None else f", Ti = {vel.Ti_s:.4g} s")
        ),
        configured_position="" if pos is None else f"Kv = {pos.Kv_1_s:.4g} 1/s",
        effort_per_m_s=_effort_per_m_s(cur is not None),
    )  # fmt: skip


def _effort_per_m_s(current_loop: bool) -> str:
    """The velocity loop's gain unit: A s/m into a current loop, else drive input per m/s."""
    return "A s/m" if current_loop else "per m/s (drive input unit)"
