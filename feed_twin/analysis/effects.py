"""The library of effects a twin may miss, their signatures, and how to rank them.

Each effect is a plant component (or a parameter of one) of the integrated model. Its signature
is a small set of regressors, functions of the measured motion, that the residual it causes
would follow. Ranking projects a residual onto each effect's regressors (ordinary least squares):
the explained fraction is `||P r||^2 / ||r||^2`, and a partial F-test on an effective sample
count tells whether it is more than chance.

The noise an effect is tested against is what remains after ALL signatures of the domain are
fitted at once (so the structure of a second hidden effect does not count as noise). Residuals
of a 1 kHz record are strongly correlated from sample to sample, so n samples carry far fewer
than n independent observations: with the lag-1 autocorrelation rho of that remaining residual,
an AR(1) process has `n_eff = n (1 - rho) / (1 + rho)` (Bartlett's correction), and projecting
such noise onto p regressors gives about (n / n_eff) times the white-noise energy. Hence
`F = (ESS / p) * n_eff / RSS_all` against F(p, n_eff - p_all). An effect counts as found only if
the test rejects at `ALPHA` *and* it explains at least `MIN_EXPLAINED` of the residual, so a huge
record cannot make a negligible effect significant.

Domains: force-like effects act on the drive effort; position-like effects (sensor delay, lead
error, backlash with a linear scale, thermal growth) act on the measured position. A missing
force also moves the following error through the closed loop, so before position-domain
effects are ranked, the part of the position residual that the effort residual explains
(through a low-pass, the loop's disturbance compliance) is removed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import signal as sps
from scipy import stats

ALPHA = 1e-3  # false-alarm probability of the partial F-test per effect
MIN_EXPLAINED = 0.05  # an effect must explain at least 5 % of the residual's energy
STRIBECK_SPEEDS_M_S = (0.001, 0.002, 0.004, 0.007, 0.01, 0.015, 0.02, 0.03)
COGGING_ORDERS = tuple(range(1, 25))  # harmonics per motor revolution searched for cogging
SMOOTH_VELOCITY_S = 0.005  # [s] smoothing window for velocity and acceleration estimates

Domain = Literal["effort", "position"]


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
    )


def _rate(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Time derivative by a 5-sample quadratic Savitzky-Golay filter (smooths the sample noise)."""
    h = float((t[-1] - t[0]) / (len(t) - 1))
    return sps.savgol_filter(np.asarray(y, dtype=float), 5, 2, deriv=1, delta=h)


def _sign(m: Motion) -> np.ndarray:
    return np.tanh(m.v_m_s / m.speed_eps)


def _moving(m: Motion) -> np.ndarray:
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


def _stiffness(m: Motion) -> dict[str, np.ndarray]:
    # the table lags the nut by F * c(x): a screw held at one end (fixed-free) has c linear
    # in the distance to the bearing, one held at both ends (fixed-fixed) c ~ x (L - x); a
    # quadratic in the position covers both (the constant part: bearings and nut). The twin's
    # effort stands for the axial load F.
    assert m.effort_sim is not None
    s = (m.x_m - m.x_m.mean()) / max(float(np.ptp(m.x_m)), 1e-9)
    f = m.effort_sim
    return {"f": f, "f_x": f * s, "f_x2": f * s * s}


def _last_direction(m: Motion) -> np.ndarray:
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
        component="GuideFriction.F_s, v_s",
        words="extra break-away friction at low speed that fades as speed rises (stick-slip)",
        choices=_stribeck_choices,
    ),
    Effect(
        name="asymmetric_friction",
        domain="effort",
        component="GuideFriction (separate forward/backward F_c, F_v)",
        words="friction that differs between the two directions of travel (worn or fatigued "
        "screw, uneven preload)",
        signature=lambda m: {"abs_v": np.abs(m.v_m_s), "moving": _moving(m)},
    ),
    Effect(
        name="constant_force",
        domain="effort",
        component="ConstantForce.f",
        words="a constant force in one direction (gravity on a vertical axis, an unbalanced "
        "counterweight, an offset in the force measurement)",
        signature=lambda m: {"one": np.ones_like(m.t_s)},
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
        domain="effort",
        component="Inverter.dead_time",
        words="an effort error that flips with the sign of the current: inverter dead time "
        "eats part of the voltage at every current reversal",
        needs=("effort_sim",),
        signature=lambda m: {"sign_effort": np.tanh(m.effort_sim / (0.02 * np.ptp(m.effort_sim)))},
    ),
    Effect(
        name="backlash",
        domain="position",
        component="Backlash.gap",
        words="lost motion at every reversal: the table stays behind by a fixed gap when the "
        "direction changes",
        signature=lambda m: {"last_direction": _last_direction(m)},
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
BY_NAME = {e.name: e for e in LIBRARY}


@dataclass(frozen=True, kw_only=True)
class Candidate:
    """How well one effect's signature explains a residual."""

    effect: Effect
    variant: str  # the chosen nonlinear parameter, "" if none
    explained_fraction: float  # [1] share of the residual energy the regressors explain
    f_statistic: float
    p_value: float
    n_eff: float  # effective number of independent samples behind the test
    coefficients: dict[str, float]  # regressor name -> least-squares coefficient
    significant: bool

    @property
    def name(self) -> str:
        return self.effect.name


def _effective_samples(e: np.ndarray) -> float:
    e = e - e.mean()
    denom = float(np.dot(e, e))
    rho = float(np.dot(e[1:], e[:-1]) / denom) if denom > 0 else 0.0
    rho = min(max(rho, 0.0), 0.9999)
    return len(e) * (1.0 - rho) / (1.0 + rho)


def test_regressors(
    r: np.ndarray, regressors: dict[str, np.ndarray], nuisance: np.ndarray | None = None
) -> tuple:
    """Least squares of r on the regressors; (explained, F, p, n_eff, coefficients).

    `nuisance` columns (e.g. a constant for a position offset that alignment owns) are projected
    out of r and the regressors first (Frisch-Waugh), so they neither count as explained nor
    bias the weights.
    """
    names = list(regressors)
    Z = np.column_stack([np.asarray(regressors[k], dtype=float) for k in names])
    if nuisance is not None:
        q, _ = np.linalg.qr(nuisance.reshape(len(r), -1))
        r = r - q @ (q.T @ r)
        Z = Z - q @ (q.T @ Z)
    scale = np.linalg.norm(Z, axis=0)
    scale[scale == 0.0] = 1.0
    coef, *_ = np.linalg.lstsq(Z / scale, r, rcond=None)
    coef = coef / scale
    fitted = Z @ coef
    e = r - fitted
    total = float(np.dot(r, r))
    rss = float(np.dot(e, e))
    explained = 0.0 if total == 0.0 else max(0.0, 1.0 - rss / total)
    p = len(names)
    n_eff = max(_effective_samples(e), p + 2.0)
    dof = n_eff - p
    f_stat = ((total - rss) / p) / (rss / dof) if rss > 0 else math.inf
    p_value = float(stats.f.sf(f_stat, p, dof)) if math.isfinite(f_stat) else 0.0
    return explained, f_stat, p_value, n_eff, dict(zip(names, map(float, coef), strict=True))


test_regressors.__test__ = False  # a library function, not a pytest test


def available(effect: Effect, motion: Motion, domains: set[str]) -> bool:
    if effect.domain not in domains:
        return False
    return all(getattr(motion, need) is not None for need in effect.needs)


def rank(
    motion: Motion,
    *,
    effort_residual: np.ndarray | None,
    position_residual: np.ndarray | None,
    exclude: tuple[str, ...] = (),
    loop_stiffness: float | None = None,
) -> list[Candidate]:
    """Rank the library's effects on the residuals, most explaining first.

    Effort-domain effects are ranked on the effort residual, position-domain effects on the
    position residual with the effort-driven part removed (see the module docstring). A record
    without effort (a scope that logged positions only) ranks the effort-domain effects on
    `loop_stiffness * position residual` [N/m * m]: a stiff position loop turns a missing force
    d into a following-error change d / K, so that is the force the twin lacks.
    """
    if effort_residual is None and position_residual is not None and loop_stiffness:
        rp = np.asarray(position_residual, dtype=float)
        effort_residual = loop_stiffness * rp
        position_residual = None
    domains = set()
    # a constant position offset belongs to the alignment, not to any effect
    offset = np.ones_like(motion.t_s)
    residual_of: dict[str, np.ndarray] = {}
    if effort_residual is not None:
        domains.add("effort")
        residual_of["effort"] = np.asarray(effort_residual, dtype=float)
    if position_residual is not None:
        domains.add("position")
        rp = np.asarray(position_residual, dtype=float)
        if effort_residual is not None:
            coupled = {"effort_residual": _lowpass(residual_of["effort"], motion)}
            _, _, _, _, coef = test_regressors(rp, coupled, offset)
            rp = rp - coef["effort_residual"] * coupled["effort_residual"]
        residual_of["position"] = rp
    best_of: list[tuple[Effect, str, dict[str, np.ndarray], tuple, int]] = []
    for effect in LIBRARY:
        if effect.name in exclude or not available(effect, motion, domains):
            continue
        r = residual_of[effect.domain]
        nuisance = offset if effect.domain == "position" else None
        variants = effect.variants(motion)
        best = None
        for label, sig in variants:
            regs = sig(motion)
            result = test_regressors(r, regs, nuisance)
            if best is None or result[0] > best[2][0]:
                best = (label, regs, result)
        assert best is not None
        best_of.append((effect, best[0], best[1], best[2], len(variants)))
    noise = {
        d: _noise_level(
            residual_of[d],
            [b for b in best_of if b[0].domain == d],
            offset if d == "position" else None,
        )
        for d in domains
    }
    out: list[Candidate] = []
    for effect, label, regs, result, n_variants in best_of:
        explained, _, _, _, coef = result
        r = residual_of[effect.domain]
        if effect.domain == "position":
            r = r - r.mean()
        rss_full, n_eff, p_full = noise[effect.domain]
        p = len(regs)
        ess = explained * float(np.dot(r, r))
        # see the module docstring: the noise level and its effective sample count come from
        # the residual of all signatures together, so another effect's structure is not noise
        f_stat = (ess / p) * n_eff / rss_full if rss_full > 0 else math.inf
        dof = max(n_eff - p_full, 1.0)
        p_value = float(stats.f.sf(f_stat, p, dof)) if math.isfinite(f_stat) else 0.0
        # the variant search is one more free parameter, which the F-test's p does not see;
        # Bonferroni over the variants keeps the false-alarm rate at ALPHA
        p_adj = min(1.0, p_value * n_variants)
        out.append(
            Candidate(
                effect=effect,
                variant=label,
                explained_fraction=explained,
                f_statistic=f_stat,
                p_value=p_adj,
                n_eff=n_eff,
                coefficients=coef,
                significant=p_adj < ALPHA and explained >= MIN_EXPLAINED,
            )
        )
    out.sort(key=lambda c: (c.significant, c.explained_fraction), reverse=True)
    return out


def _noise_level(r: np.ndarray, entries: list, nuisance: np.ndarray | None):
    """(RSS, effective samples, parameters) of r after all the domain's signatures at once."""
    columns = [np.asarray(v, dtype=float) for e in entries for v in e[2].values()]
    if nuisance is not None:
        columns.append(nuisance)
    if not columns:
        return float(np.dot(r, r)), _effective_samples(r), 0
    Z = np.column_stack(columns)
    scale = np.linalg.norm(Z, axis=0)
    scale[scale == 0.0] = 1.0
    coef, _, rank_z, _ = np.linalg.lstsq(Z / scale, r, rcond=None)
    e = r - (Z / scale) @ coef
    return float(np.dot(e, e)), _effective_samples(e), int(rank_z)


def _lowpass(r: np.ndarray, motion: Motion) -> np.ndarray:
    h = float((motion.t_s[-1] - motion.t_s[0]) / (len(motion.t_s) - 1))
    window = max(5, int(round(0.02 / h)) | 1)
    return sps.savgol_filter(r, window, 1)


def evidence(candidate: Candidate, unit: str) -> str:
    """The finding in plain machine-tool words, with the numbers behind it."""
    c = candidate
    variant = f" ({c.variant})" if c.variant else ""
    coefs = ", ".join(f"{k} {v:+.4g}" for k, v in c.coefficients.items())
    verdict = "significant" if c.significant else "not significant"
    return (
        f"{c.effect.words}{variant}: its signature explains "
        f"{100 * c.explained_fraction:.1f} % of the {c.effect.domain} residual "
        f"(F = {c.f_statistic:.3g} on about {c.n_eff:.0f} independent samples, "
        f"p = {c.p_value:.2g}, {verdict}); least-squares weights {coefs} [{unit}]"
    )
