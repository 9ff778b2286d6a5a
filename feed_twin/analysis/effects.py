"""The library of effects a twin may miss and their signatures.

Each effect is a plant component (or a parameter of one) of the integrated model. Its signature
is a small set of regressors, functions of the measured motion, that the residual it causes
would follow; feed_twin.analysis.ranking projects residuals onto them and tests them.

Domains: force-like effects act on the drive effort; position-like effects (sensor delay, lead
error, backlash with a linear scale, thermal growth) act on the measured position. The
inverter's dead time acts on the voltage: it is ranked on the q-axis voltage the current
controller commands, when the record has it, and falls back to the effort otherwise.

Dead time. A two-level inverter leg with interlock time T_d at PWM period T_s loses about
u_dc T_d / T_s of its pole voltage while its phase current i_x flows out of the leg and gains
it while the current flows in: an error -u_dc (T_d/T_s) sgn(i_x) per phase (the device drop
u_f sgn(i_x) has the same shape and is not told apart from it; the feed_twin Inverter smooths
sgn over the PWM current ripple i_reg). The Park transform of these three square waves at
i_d ~ 0 is a voltage along the current vector of mean (4/pi) u_dc T_d/T_s sgn(i_q) with a ripple
at six times the electrical frequency. A drive's PI current loop (and its dead-time
compensation, tuned for the nominal T_d) supplies the missing voltage within a few current-loop
periods, so the current, and through it the effort and the following error, keep only a small
trace; the voltage the controller commands carries the whole error. The signature is that
Park transform computed from the measured q-current at the electrical angle p 2 pi x / lead (x
the table position, direct drive), over a grid of sign-smoothing currents i_reg; its weight is
u_dc Delta T_d / T_s, the extra volts the controller must command. (A recorded d-voltage,
`voltage_d_V`, is not used: at i_d ~ 0 the d part of the error is only the 6th-harmonic ripple.)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import signal as sps

from feed_twin.core.smooth import smooth_sign_array
from feed_twin.plant.registry import OWNED_EFFECTS, OWNER_OF

STRIBECK_SPEEDS_M_S = (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02, 0.03)
COGGING_ORDERS = tuple(range(1, 25))  # harmonics per motor revolution searched for cogging
SMOOTH_VELOCITY_S = 0.005  # [s] smoothing window for velocity and acceleration estimates
# [A] sign-smoothing currents searched for the dead time (PWM current ripple of small to large
# drives): below i_reg the inverter's voltage error grows linearly with the phase current
DEAD_TIME_CURRENT_SCALES_A = (0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0)

Domain = Literal["effort", "position", "voltage"]


@dataclass(frozen=True, kw_only=True)
class Motion:
    """Measured motion and machine data the signatures are functions of (SI, one time base)."""

    t_s: np.ndarray
    x_m: np.ndarray  # measured table position
    v_m_s: np.ndarray  # velocity estimate
    a_m_s2: np.ndarray  # acceleration estimate
    effort_sim: np.ndarray | None  # the twin's effort on this run (for gain errors)
    lead_m: float | None  # [m/rev] screw lead (motor angle = 2 pi x / lead for a direct drive)
    pole_pairs: int | None
    travel_m: float  # [m] stroke of the axis (for stiffness that depends on position)
    current_q_A: np.ndarray | None = None  # measured q-current (or its command) [A]

    @property
    def speed_eps(self) -> float:
        """Speed [m/s] that the sign regressors use to regularise sign(v) near standstill."""
        return 0.002 * float(np.max(np.abs(self.v_m_s)))


def motion_from_position(
    t_s: np.ndarray,
    x_m: np.ndarray,
    *,
    effort_sim: np.ndarray | None,
    lead_m: float | None,
    pole_pairs: int | None,
    travel_m: float,
    current_q_A: np.ndarray | None = None,
) -> Motion:
    """Velocity and acceleration from a measured position by Savitzky-Golay differentiation.

    A quadratic fitted over SMOOTH_VELOCITY_S suppresses encoder quantisation, which plain
    differences would amplify by 1/h (and 1/h^2 for the acceleration).
    """
    t = np.asarray(t_s, dtype=float)
    h = float((t[-1] - t[0]) / (len(t) - 1))
    window = max(5, int(round(SMOOTH_VELOCITY_S / h)) | 1)
    x = np.asarray(x_m, dtype=float)
    v = sps.savgol_filter(x, window, 2, deriv=1, delta=h)
    a = sps.savgol_filter(x, 2 * window + 1, 2, deriv=2, delta=h)
    return Motion(
        t_s=t,
        x_m=x,
        v_m_s=v,
        a_m_s2=a,
        effort_sim=effort_sim,
        lead_m=lead_m,
        pole_pairs=pole_pairs,
        travel_m=travel_m,
        current_q_A=None if current_q_A is None else np.asarray(current_q_A, dtype=float),
    )


def _rate(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Time derivative by a 5-sample quadratic Savitzky-Golay filter (smooths the sample noise)."""
    h = float((t[-1] - t[0]) / (len(t) - 1))
    return sps.savgol_filter(np.asarray(y, dtype=float), 5, 2, deriv=1, delta=h)


def _sign(m: Motion) -> np.ndarray:
    return np.tanh(m.v_m_s / m.speed_eps)


def moving(m: Motion) -> np.ndarray:
    return np.abs(_sign(m))


Signature = Callable[[Motion], dict[str, np.ndarray]]


@dataclass(frozen=True, kw_only=True)
class Effect:
    """One entry of the library."""

    name: str
    domain: Domain
    component: str  # plant component (or component.parameter) of the integrated model
    words: str  # what a machine-tool engineer calls it
    needs: tuple[str, ...] = ()  # Motion fields that must be known: lead_m, pole_pairs, ...
    signature: Signature | None = field(default=None, repr=False)
    # the domain ranked when the record lacks this effect's own residual (dead time without
    # voltages: the effort, where the current loop leaves only a trace of it)
    fallback: Domain | None = None
    # variants over a nonlinear parameter (Stribeck speed, cogging order); the best one is used
    choices: Callable[[Motion], list[tuple[str, Signature]]] | None = field(
        default=None, repr=False
    )

    def __post_init__(self) -> None:
        if (self.signature is None) == (self.choices is None):
            raise ValueError(f"effect {self.name}: give exactly one of signature and choices")

    def variants(self, motion: Motion) -> list[tuple[str, Signature]]:
        if self.choices is not None:
            return self.choices(motion)
        assert self.signature is not None
        return [("", self.signature)]


def _stribeck_choices(m: Motion) -> list[tuple[str, Signature]]:
    def make(vs: float) -> Signature:
        return lambda mm: {"stribeck": _sign(mm) * np.exp(-((mm.v_m_s / vs) ** 2))}

    return [(f"v_s = {vs:g} m/s", make(vs)) for vs in STRIBECK_SPEEDS_M_S]


def _motor_angle(m: Motion) -> np.ndarray:
    assert m.lead_m is not None
    return 2.0 * math.pi * m.x_m / m.lead_m


def _cogging_choices(m: Motion) -> list[tuple[str, Signature]]:
    def make(k: int) -> Signature:
        return lambda mm: {
            "sin": np.sin(k * _motor_angle(mm)),
            "cos": np.cos(k * _motor_angle(mm)),
        }

    # once per electrical revolution (order = pole pairs) is current_offset's signature: a
    # cogging torque repeats lcm(slots, 2 p) times per revolution, never p times
    orders = [k for k in COGGING_ORDERS if k != m.pole_pairs]
    return [(f"order {k} per motor revolution", make(k)) for k in orders]


def _electrical(m: Motion) -> dict[str, np.ndarray]:
    assert m.pole_pairs is not None
    theta = m.pole_pairs * _motor_angle(m)
    return {"sin": np.sin(theta), "cos": np.cos(theta)}


def dead_time_voltage(
    i_q_A: np.ndarray, theta_e_rad: np.ndarray, i_reg_A: float
) -> dict[str, np.ndarray]:
    """d/q components of the three phases' smooth sgn(i_x / i_reg) at i_d = 0 (see module doc).

    Amplitude-invariant Clarke and Park, as the drive's controller uses them: for |i_q| >> i_reg
    the q component averages (4/pi) sgn(i_q) over an electrical revolution and ripples at six
    times the electrical frequency.
    """
    i_alpha = -np.sin(theta_e_rad) * i_q_A
    i_beta = np.cos(theta_e_rad) * i_q_A
    half = 0.5 * math.sqrt(3.0) * i_beta
    phases = (i_alpha, -0.5 * i_alpha + half, -0.5 * i_alpha - half)
    s_a, s_b, s_c = (smooth_sign_array(x, i_reg_A) for x in phases)
    s_alpha = (2.0 / 3.0) * (s_a - 0.5 * (s_b + s_c))
    s_beta = (s_b - s_c) / math.sqrt(3.0)
    return {
        "d": np.cos(theta_e_rad) * s_alpha + np.sin(theta_e_rad) * s_beta,
        "q": -np.sin(theta_e_rad) * s_alpha + np.cos(theta_e_rad) * s_beta,
    }


def _dead_time_choices(m: Motion) -> list[tuple[str, Signature]]:
    def make(i_reg: float) -> Signature:
        def signature(mm: Motion) -> dict[str, np.ndarray]:
            assert mm.current_q_A is not None and mm.pole_pairs is not None
            theta_e = mm.pole_pairs * _motor_angle(mm)
            return {"sgn_i_q": dead_time_voltage(mm.current_q_A, theta_e, i_reg)["q"]}

        return signature

    return [(f"i_reg = {i:g} A", make(i)) for i in DEAD_TIME_CURRENT_SCALES_A]


def _stiffness(m: Motion) -> dict[str, np.ndarray]:
    # the table lags the nut by F * c(x): a screw held at one end (fixed-free) has c linear
    # in the distance to the bearing, one held at both ends (fixed-fixed) c ~ x (L - x); a
    # quadratic in the position covers both (the constant part: bearings and nut). The twin's
    # effort stands for the axial load F.
    assert m.effort_sim is not None
    s = (m.x_m - m.x_m.mean()) / max(float(np.ptp(m.x_m)), 1e-9)
    f = m.effort_sim
    return {"f": f, "f_x": f * s, "f_x2": f * s * s}


def last_direction(m: Motion) -> np.ndarray:
    """Direction of the last motion, held through stops: +1, -1, or 0 before the first move.

    Lost motion at a reversal leaves the table behind the nut by the half gap on the trailing
    side, and it stays there while the axis stands still (friction holds the table), so the
    position error follows the direction of the LAST move, not sign(v), which is 0 at rest.
    """
    moving = np.abs(m.v_m_s) > 5.0 * m.speed_eps
    direction = np.where(moving, np.sign(m.v_m_s), 0.0)
    last = np.maximum.accumulate(np.where(moving, np.arange(len(direction)), 0))
    held = direction[last]
    held[: int(np.argmax(moving))] = 0.0  # no move yet: the contact state is unknown
    return held


def _thermal(m: Motion) -> dict[str, np.ndarray]:
    # a screw still far from thermal equilibrium warms in proportion to the distance travelled
    # D(t); its heated length from the fixed bearing is x_0 + x with x_0 unknown here, so the
    # elongation alpha dT (x_0 + x) is a combination of D x and D
    dt = np.diff(m.t_s, prepend=m.t_s[0])
    travelled = np.cumsum(np.abs(m.v_m_s) * dt)
    return {"x_D": m.x_m * travelled, "D": travelled}


LIBRARY: tuple[Effect, ...] = (
    Effect(
        name="coulomb_friction",
        domain="effort",
        component="GuideFriction.F_c",
        words="a constant friction force that changes sign with the direction of motion",
        signature=lambda m: {"sign_v": _sign(m)},
    ),
    Effect(
        name="viscous_friction",
        domain="effort",
        component="GuideFriction.F_v",
        words="a friction force that grows in proportion to speed (lubricant, seals)",
        signature=lambda m: {"v": m.v_m_s},
    ),
    Effect(
        name="stribeck_friction",
        domain="effort",
        component="GuideFriction.dF_s, v_s",
        words="extra break-away friction at low speed that fades as speed rises (stick-slip)",
        choices=_stribeck_choices,
    ),
    Effect(
        name="asymmetric_friction",
        domain="effort",
        component="GuideFriction (separate forward/backward F_c, F_v)",
        words="friction that differs between the two directions of travel (worn or fatigued "
        "screw, uneven preload)",
        signature=lambda m: {"abs_v": np.abs(m.v_m_s), "moving": moving(m)},
    ),
    Effect(
        name="mass_error",
        domain="effort",
        component="Mass.m",
        words="a force proportional to acceleration: the moving mass differs from the model",
        signature=lambda m: {"a": m.a_m_s2},
    ),
    Effect(
        name="torque_constant_error",
        domain="effort",
        component="drive gain (ForceSource.gain / Pmsm.psi_pm)",
        words="the whole effort is off by a fixed ratio: the torque (force) constant of the "
        "drive differs from the data sheet",
        needs=("effort_sim",),
        signature=lambda m: {"effort": m.effort_sim},
    ),
    Effect(
        name="cogging_torque",
        domain="effort",
        component="Pmsm.cogging",
        words="a force ripple that repeats a fixed number of times per motor revolution",
        needs=("lead_m",),
        choices=_cogging_choices,
    ),
    Effect(
        name="current_offset",
        domain="effort",
        component="CurrentSensor.offset_a, offset_b, offset_c",
        words="a force ripple once per electrical revolution: an offset in a phase-current "
        "measurement",
        needs=("lead_m", "pole_pairs"),
        signature=_electrical,
    ),
    Effect(
        name="dead_time",
        domain="voltage",
        fallback="effort",
        component="Inverter.t_dead",
        words="a voltage error that flips with the sign of the phase currents and ripples six "
        "times per electrical revolution: the inverter's dead time eats part of every phase "
        "voltage, and the current controller must command the missing volts",
        needs=("current_q_A", "lead_m", "pole_pairs"),
        choices=_dead_time_choices,
    ),
    Effect(
        name="measurement_delay",
        domain="effort",
        component="Encoder/LinearScale.delay_ticks",
        words="the loop acts on a position measured late: the effort follows the twin's "
        "effort shifted in time (sensor sample delay, slow fieldbus)",
        needs=("effort_sim",),
        signature=lambda m: {"effort_rate": _rate(m.effort_sim, m.t_s)},
    ),
    Effect(
        name="channel_delay",
        domain="effort",
        component="the record: analysis.effort_delay_s (trace side, outside every loop)",
        words="the recorder stamps the effort later (or earlier) than the position: the "
        "effort follows the twin's shifted in time while the following error does not move",
        needs=("effort_sim",),
        signature=lambda m: {"effort_rate": _rate(m.effort_sim, m.t_s)},
    ),
    Effect(
        name="lead_error",
        domain="position",
        component="BallScrew.lead_error",
        words="a position error that repeats once per screw revolution (pitch error, eccentricity)",
        needs=("lead_m",),
        signature=lambda m: {
            "sin": np.sin(_motor_angle(m)),
            "cos": np.cos(_motor_angle(m)),
        },
    ),
    Effect(
        name="thermal_drift",
        domain="position",
        component="ThermalGrowth.heating",
        words="a position error that grows slowly with the distance travelled and with the "
        "distance from the fixed bearing: the screw heats up and lengthens",
        signature=_thermal,
    ),
    Effect(
        name="position_dependent_stiffness",
        domain="position",
        component="AxialCompliance (screw stiffness k(x))",
        words="the table lags more under load in mid-travel than near the bearings: the "
        "screw's axial stiffness depends on the table position",
        needs=("effort_sim",),
        signature=_stiffness,
    ),
)
# the effects declared by their components (feed_twin.plant.component.OwnedEffect)
LIBRARY += tuple(
    Effect(
        name=owned.name,
        domain=owned.domain,
        component=f"{OWNER_OF[owned.name]}.{owned.parameters}",
        words=owned.words,
        needs=owned.needs,
        signature=owned.signature,
    )
    for owned in OWNED_EFFECTS
)
BY_NAME = {e.name: e for e in LIBRARY}
