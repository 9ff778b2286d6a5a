"""The `controller:` section of an axis config: which loops exist, their rates, gains, limits.

Frozen parameter dataclasses, validated on construction, loaded through
feed_twin.core.config.from_mapping so that errors read `file: controller.field = value: reason`.
feed_twin.control.cascade turns a ControllerConfig into the flat vectors its compiled tick reads.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from feed_twin.core.config import from_mapping
from feed_twin.core.validate import (
    require_integer_multiple,
    require_nonnegative,
    require_positive,
    require_range,
)

TWO_PI = 2.0 * math.pi
MAX_FIR_TAPS = 16

Mode = Literal["position", "velocity", "torque"]
MODE_CODES = {"position": 0, "velocity": 1, "torque": 2}
MODE_POSITION = 0
MODE_VELOCITY = 1
MODE_TORQUE = 2

Interpolation = Literal["hold", "linear", "extrapolate", "cubic"]
INTERPOLATION_CODES = {"hold": 0, "linear": 1, "extrapolate": 2, "cubic": 3}
INTERP_HOLD = 0
INTERP_LINEAR = 1
INTERP_EXTRAPOLATE = 2
INTERP_CUBIC = 3

FeedForwardRate = Literal["position", "velocity"]


def require_choice(name: str, value: str, choices: tuple[str, ...]) -> None:
    """Literal fields checked again for direct construction (the YAML loader checks them too)."""
    if value not in choices:
        raise ValueError(f"{name} = {value!r}: must be one of {', '.join(map(repr, choices))}")


@dataclass(frozen=True, kw_only=True)
class DriveConfig:
    """The controller's own copy of the drive facts it needs (load-side signals, motor-side plant).

    `K_t` converts the velocity loop's output unit into motor torque: N m/A for a PMSM with a
    current loop (1.5 * p * psi_pm for the amplitude-invariant frame), N m per drive input unit for
    an ideal torque/force source (for a linear drive command in N per unit, multiply by
    lead / (2*pi)).
    """

    lead_m: float  # screw lead [m/rev]; converts encoder angle to table position
    J_total_kg_m2: float  # total inertia reflected to the motor shaft [kg m^2]
    K_t: float  # motor torque per unit of effort [N m/A or N m/unit]
    effort_limit: float  # current limit [A] or drive-input saturation [unit], symmetric

    def __post_init__(self) -> None:
        require_positive("lead_m", self.lead_m)
        require_positive("J_total_kg_m2", self.J_total_kg_m2)
        require_positive("K_t", self.K_t)
        require_positive("effort_limit", self.effort_limit)


@dataclass(frozen=True, kw_only=True)
class PositionLoopConfig:
    period_s: float  # sample period [s], an integer multiple of the base period
    Kv_1_s: float  # position gain [1/s] (velocity per following error)
    feedback: Literal["motor_encoder", "linear_scale"]  # semi-closed or closed loop
    velocity_ff: float = 0.0  # velocity feed-forward gain [-], 0..1
    acceleration_ff: float = 0.0  # acceleration feed-forward gain [-], 0..1
    interpolation: Interpolation = "linear"  # fine interpolation of the NC setpoints
    # where the feed-forwards are fine-interpolated and added: once per position-loop sample
    # (held over it), or once per velocity-loop sample (the position loop's own output held)
    feed_forward_rate: FeedForwardRate = "position"
    following_error_limit_m: float | None = None  # trip level [m]; None: no monitoring
    velocity_limit_m_s: float | None = None  # clamp of the velocity command [m/s]

    def __post_init__(self) -> None:
        require_positive("period_s", self.period_s)
        require_choice("feedback", self.feedback, ("motor_encoder", "linear_scale"))
        require_choice("interpolation", self.interpolation, tuple(INTERPOLATION_CODES))
        require_choice("feed_forward_rate", self.feed_forward_rate, ("position", "velocity"))
        require_nonnegative("Kv_1_s", self.Kv_1_s)
        require_range("velocity_ff", self.velocity_ff, 0.0, 1.0)
        require_range("acceleration_ff", self.acceleration_ff, 0.0, 1.0)
        if self.following_error_limit_m is not None:
            require_positive("following_error_limit_m", self.following_error_limit_m)
        if self.velocity_limit_m_s is not None:
            require_positive("velocity_limit_m_s", self.velocity_limit_m_s)


@dataclass(frozen=True, kw_only=True)
class VelocityEstimatorConfig:
    fir_taps: tuple[float, ...] = (1.0,)  # weights of the latest differences [-], sum 1
    lowpass_hz: float | None = None  # first-order low-pass after the FIR [Hz]; None: off

    def __post_init__(self) -> None:
        if not 1 <= len(self.fir_taps) <= MAX_FIR_TAPS:
            raise ValueError(
                f"fir_taps = {list(self.fir_taps)!r}: must have 1 to {MAX_FIR_TAPS} entries"
            )
        for i, tap in enumerate(self.fir_taps):
            require_range(f"fir_taps[{i}]", tap, -1e6, 1e6)
        if abs(sum(self.fir_taps) - 1.0) > 1e-9:
            raise ValueError(
                f"fir_taps = {list(self.fir_taps)!r}: must sum to 1 (unit gain on a ramp), "
                f"sum is {sum(self.fir_taps)!r}"
            )
        if self.lowpass_hz is not None:
            require_positive("lowpass_hz", self.lowpass_hz)


@dataclass(frozen=True, kw_only=True)
class NotchConfig:
    frequency_hz: float  # centre frequency [Hz]
    bandwidth_hz: float  # width [Hz]
    depth: float  # gain at the centre [-], 0 (full notch) .. 1 (no notch)

    def __post_init__(self) -> None:
        require_positive("frequency_hz", self.frequency_hz)
        require_positive("bandwidth_hz", self.bandwidth_hz)
        require_range("depth", self.depth, 0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class VelocityLoopConfig:
    period_s: float  # sample period [s], an integer multiple of the base period
    Kp: float  # proportional gain [effort unit per m/s], e.g. A/(m/s)
    Ti_s: float | None = None  # integral time [s]; None: P only
    estimator: VelocityEstimatorConfig = dataclasses.field(default_factory=VelocityEstimatorConfig)
    setpoint_lowpass_hz: float | None = None  # 2nd-order low-pass on the current setpoint [Hz]
    notch: NotchConfig | None = None  # notch on the current setpoint

    def __post_init__(self) -> None:
        require_positive("period_s", self.period_s)
        require_nonnegative("Kp", self.Kp)
        if self.Ti_s is not None:
            require_positive("Ti_s", self.Ti_s)
        if self.setpoint_lowpass_hz is not None:
            require_positive("setpoint_lowpass_hz", self.setpoint_lowpass_hz)


@dataclass(frozen=True, kw_only=True)
class CurrentLoopConfig:
    period_s: float  # sample period [s], an integer multiple of the base period
    pole_pairs: int  # [-]
    R_s_ohm: float  # stator resistance [ohm] (for tuning and margins)
    L_d_H: float  # d inductance [H] (decoupling)
    L_q_H: float  # q inductance [H] (decoupling)
    psi_pm_Vs: float  # permanent-magnet flux linkage [V s] (back-EMF feed-forward)
    Kp_d_V_A: float  # d-axis proportional gain [V/A]
    Ti_d_s: float  # d-axis integral time [s]
    Kp_q_V_A: float  # q-axis proportional gain [V/A]
    Ti_q_s: float  # q-axis integral time [s]
    decoupling: bool = True  # cross-coupling compensation -/+ omega_e * L * i
    back_emf_ff: bool = True  # omega_e * psi_pm feed-forward on u_q
    voltage_margin: float = 1.0  # usable fraction of the linear range u_dc/sqrt(3) [-]
    angle_advance_periods: float = 0.0  # delay compensation: advance by omega_e*T_i*this [-]
    encoder_offset_rad: float = 0.0  # electrical angle of the d axis at encoder zero [rad]
    i_trip_A: float | None = None  # overcurrent trip level on |i_a|,|i_b|,|i_c| [A]
    # Dead-time compensation: each phase reference gets u_comp * clip(i_x / band, -1, 1) added,
    # the voltage the inverter loses to dead time and device drop, about t_dead*f_pwm*u_dc + u_f.
    dead_time_comp_V: float = 0.0  # [V]; 0 = off
    dead_time_comp_band_A: float = 0.5  # current over which the correction changes sign [A]

    def __post_init__(self) -> None:
        require_positive("period_s", self.period_s)
        # YAML may give a float or a bool where the annotation says int
        if isinstance(self.pole_pairs, bool) or not isinstance(self.pole_pairs, int):  # pyright: ignore[reportUnnecessaryIsInstance]
            raise ValueError(f"pole_pairs = {self.pole_pairs!r}: must be a whole number")
        require_positive("pole_pairs", self.pole_pairs)
        require_positive("R_s_ohm", self.R_s_ohm)
        require_positive("L_d_H", self.L_d_H)
        require_positive("L_q_H", self.L_q_H)
        require_nonnegative("psi_pm_Vs", self.psi_pm_Vs)
        require_nonnegative("Kp_d_V_A", self.Kp_d_V_A)
        require_positive("Ti_d_s", self.Ti_d_s)
        require_nonnegative("Kp_q_V_A", self.Kp_q_V_A)
        require_positive("Ti_q_s", self.Ti_q_s)
        require_range("voltage_margin", self.voltage_margin, 1e-3, 1.0)
        require_range("angle_advance_periods", self.angle_advance_periods, 0.0, 3.0)
        require_range("encoder_offset_rad", self.encoder_offset_rad, -TWO_PI, TWO_PI)
        if self.i_trip_A is not None:
            require_positive("i_trip_A", self.i_trip_A)
        require_nonnegative("dead_time_comp_V", self.dead_time_comp_V)
        require_positive("dead_time_comp_band_A", self.dead_time_comp_band_A)


@dataclass(frozen=True, kw_only=True)
class ControllerConfig:
    """The `controller:` section: which loops exist, their rates, gains and limits."""

    base_period_s: float  # base tick of the engine [s] (normally the current-loop period)
    mode: Mode  # CiA 402 boundary: position (CSP), velocity (CSV), torque (CST)
    drive: DriveConfig
    nc_period_s: float = 1.0e-3  # NC interpolation period [s]
    computation_delay: bool = True  # innermost result applied one of its samples later
    enabled_at_start: bool = True  # power stage enabled in the initial state
    position: PositionLoopConfig | None = None
    velocity: VelocityLoopConfig | None = None
    current: CurrentLoopConfig | None = None

    def __post_init__(self) -> None:
        require_choice("mode", self.mode, tuple(MODE_CODES))
        require_positive("base_period_s", self.base_period_s)
        base = self.base_period_s
        require_integer_multiple("nc_period_s", self.nc_period_s, base, "base_period_s")
        for name in ("position", "velocity", "current"):
            loop = getattr(self, name)
            if loop is not None:
                require_integer_multiple(f"{name}.period_s", loop.period_s, base, "base_period_s")
        if self.position is not None:
            require_integer_multiple(
                "nc_period_s", self.nc_period_s, self.position.period_s, "position.period_s"
            )
        if self.position is not None and self.velocity is None:
            raise ValueError("position: a position loop needs a velocity loop under it")
        needs = {"position": ("position", "velocity"), "velocity": ("velocity",), "torque": ()}
        for loop_name in needs[self.mode]:
            if getattr(self, loop_name) is None:
                raise ValueError(f"mode = {self.mode!r}: needs a {loop_name} section")
        if self.velocity is not None:
            vel = self.velocity
            nyquist = 0.5 / vel.period_s
            for path, value in (
                ("velocity.estimator.lowpass_hz", vel.estimator.lowpass_hz),
                ("velocity.setpoint_lowpass_hz", vel.setpoint_lowpass_hz),
                ("velocity.notch.frequency_hz", vel.notch.frequency_hz if vel.notch else None),
            ):
                if value is not None and value >= nyquist:
                    raise ValueError(
                        f"{path} = {value!r}: must lie below the velocity loop's Nyquist "
                        f"frequency {nyquist!r} Hz"
                    )


def load_controller_config(mapping: Mapping[str, Any], source: str) -> ControllerConfig:
    """Build a ControllerConfig from the `controller:` mapping of a YAML file.

    Errors are `ConfigError`s reading `<source>: controller.<field> = <value>: <reason>`.
    """
    return from_mapping(ControllerConfig, dict(mapping), source=source, path="controller")
