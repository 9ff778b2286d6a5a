"""The truth machine's parameters: a light machine-tool feed axis, written from its data sheet.

The machine is the one `config/truth_nominal.yaml` describes to the twin (same masses, lead,
force constant, friction and loop gains), but it is built here from the equations, with its own
laws, numerics and rates:
- a PMSM in the rotor frame (R-L windings, back-EMF, optional cogging) fed by an averaged
  inverter with dead time, behind a discrete PI current loop at `f_current_hz` that acts one
  period late, on phase currents measured with per-phase offsets;
- three inertias: rotor (+ hub), screw (+ hub) through a torsional coupling, and the table
  through the screw's axial spring 1/k(x) = 1/k_bearing + (x_0 + x)/EA (fixed-free), with a
  dead zone (backlash) between nut and table, a periodic lead error and thermal growth of the
  screw;
- table friction: Coulomb + viscous + Stribeck with an arctangent regularisation, per
  direction, optionally sticking (Karnopp: held at rest while the applied force is below the
  holding force) and optionally growing linearly over the record (drift);
- gravity on an unbalanced mass (a vertical axis);
- a velocity PI at `f_velocity_hz` on a backward-difference speed of the quantised motor
  encoder, and a position P loop at `f_position_hz`, closed on the motor encoder (semi-closed
  loop), whose measurement may come late; the speed feed-forward enters at the velocity rate;
- NC setpoints fine-interpolated by a cubic Hermite spline, one NC period late.
SI units throughout; table coordinate x [m], positive away from the motor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

G_N_KG = 9.80665  # standard gravity [m/s^2]


_SIGNED = frozenset(
    ("offset_a", "offset_b", "offset_c", "F_ext", "cogging_phase", "lead_error_phase")
)
_NONNEGATIVE = frozenset(
    (
        "setpoint_latency_s", "b_m", "t_dead", "cogging_Nm", "d_c", "backlash", "lead_error_m",
        "heating_K_m", "F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg", "dF_s", "F_hold",
        "friction_drift_per_s", "m_unbalanced", "feedback_delay_s", "velocity_ff",
    )
)  # fmt: skip
_WHOLE = ("pole_pairs", "cogging_order", "substeps", "encoder_counts")


def _check(obj: object) -> None:
    """Range checks of a parameter dataclass: finite; >= 0 or > 0 unless signed."""
    for f in fields(obj):  # type: ignore[arg-type]
        value = getattr(obj, f.name)
        if not math.isfinite(value):
            raise ValueError(f"{f.name} = {value!r}: must be finite")
        if f.name in _NONNEGATIVE and value < 0.0:
            raise ValueError(f"{f.name} = {value!r}: must be >= 0")
        if f.name not in _NONNEGATIVE | _SIGNED and value <= 0.0:
            raise ValueError(f"{f.name} = {value!r}: must be > 0")
        if f.name in _WHOLE and int(value) != value:
            raise ValueError(f"{f.name} = {value!r}: must be a whole number")


@dataclass(frozen=True, kw_only=True)
class Machine:
    """Physical parameters of the truth machine (defaults: its nominal, data-sheet values)."""

    # motor and inverter
    R_s: float = 0.6  # stator resistance [ohm]
    L_s: float = 2.5e-3  # d and q inductance [H]
    psi_pm: float = 0.1  # permanent-magnet flux linkage [V s]
    pole_pairs: int = 3
    kt_scale: float = 1.0  # true / data-sheet flux (torque-constant error) [-]
    J_m: float = 6.0e-4  # rotor + motor hub [kg m^2]
    b_m: float = 0.0  # motor bearing viscous torque [N m s/rad]
    u_dc: float = 300.0  # DC bus [V]
    f_pwm: float = 8000.0  # switching frequency [Hz]
    t_dead: float = 0.0  # inverter dead time [s]
    cogging_order: int = 6  # cogging periods per motor revolution
    cogging_Nm: float = 0.0  # cogging amplitude [N m]
    cogging_phase: float = 0.0  # [rad]
    offset_a: float = 0.0  # phase-current sensor offsets [A]
    offset_b: float = 0.0
    offset_c: float = 0.0
    # drive train
    k_c: float = 1.2e4  # coupling torsional stiffness [N m/rad]
    d_c: float = 1.0  # coupling damping [N m s/rad]
    J_s: float = 4.0e-4  # screw + screw hub [kg m^2]
    lead: float = 0.01  # screw lead [m/rev]
    k_bearing: float = 4.0e8  # fixed bearing + nut axial stiffness [N/m]
    EA: float = 1.9e8  # screw axial rigidity E*A_root [N]
    x_0: float = 0.1  # nut distance from the fixed bearing at x = 0 [m]
    d_ax: float = 1.0e4  # axial damping [N s/m]
    backlash: float = 0.0  # total lost motion between nut and table [m]
    lead_error_m: float = 0.0  # once-per-revolution lead error amplitude [m]
    lead_error_phase: float = 0.0  # its phase [rad] at x = 0
    heating_K_m: float = 0.0  # screw temperature rise per metre travelled [K/m]
    thermal_tau_s: float = 600.0  # screw cooling time constant [s]
    alpha_K: float = 11.5e-6  # thermal expansion of steel [1/K]
    # table, friction, gravity
    m_table: float = 150.0  # table + nut + load [kg]
    F_c_pos: float = 60.0  # Coulomb force moving in +x [N]
    F_c_neg: float = 60.0  # Coulomb force moving in -x [N]
    F_v_pos: float = 300.0  # viscous coefficient moving in +x [N s/m]
    F_v_neg: float = 300.0  # moving in -x [N s/m]
    dF_s: float = 0.0  # Stribeck excess at rest [N]
    v_s: float = 0.005  # Stribeck speed [m/s]
    v_reg: float = 2.0e-5  # arctangent regularisation speed of the sliding law [m/s]
    F_hold: float = 0.0  # Karnopp holding force; > 0: the table sticks at rest [N]
    friction_drift_per_s: float = 0.0  # friction grows as (1 + rate*t) over the record [1/s]
    m_unbalanced: float = 0.0  # hanging (unbalanced) mass of a vertical axis [kg]
    F_ext: float = 0.0  # further constant force on the table, +x [N]
    # controller (gains as the drive's parameter list gives them; rates of this drive)
    f_current_hz: float = 8000.0
    f_velocity_hz: float = 4000.0
    f_position_hz: float = 2000.0
    substeps: int = 4  # integration steps per current-loop period
    Kp_i: float = 9.4  # current PI [V/A]
    Ti_i: float = 4.2e-3  # [s]
    Kp_v: float = 480.0  # velocity PI [A/(m/s)], load side
    Ti_v: float = 0.016  # [s]
    Kv: float = 40.0  # position loop [1/s]
    velocity_ff: float = 1.0
    i_max: float = 20.0  # current limit [A]
    encoder_counts: int = 1 << 20  # motor encoder counts per revolution
    feedback_delay_s: float = 0.0  # the loops' position measurement comes this late [s]
    setpoint_latency_s: float = 1.0e-3  # the drive interpolates the NC points this late [s]

    def __post_init__(self) -> None:
        _check(self)
        for slow, fast in (("f_velocity_hz", "f_current_hz"), ("f_position_hz", "f_velocity_hz")):
            ratio = getattr(self, fast) / getattr(self, slow)
            if abs(ratio - round(ratio)) > 1e-9 or ratio < 1.0:
                slow_hz, fast_hz = getattr(self, slow), getattr(self, fast)
                raise ValueError(f"{slow} = {slow_hz!r}: must divide {fast} = {fast_hz!r}")

    @property
    def K_t(self) -> float:
        """True torque constant 1.5 p psi_pm kt_scale [N m/A]."""
        return 1.5 * self.pole_pairs * self.psi_pm * self.kt_scale

    @property
    def rotary_mass(self) -> float:
        """The rotating inertias seen at the table, (J_m + J_s) (2 pi / lead)^2 [kg]."""
        return (self.J_m + self.J_s) * (2.0 * math.pi / self.lead) ** 2

    @property
    def mass_equivalent(self) -> float:
        """Everything the drive accelerates, seen at the table [kg]."""
        return self.m_table + self.rotary_mass

    def k_axial(self, x: float) -> float:
        """Axial stiffness between screw and table with the nut at x [N/m]."""
        return 1.0 / (1.0 / self.k_bearing + (self.x_0 + x) / self.EA)


NOMINAL = Machine()
