"""Ranking the effects of the library (feed_twin.analysis.effects) on a twin's residuals.

Ranking projects a residual onto each effect's regressors (ordinary least squares): the
explained fraction is `||P r||^2 / ||r||^2`, and a partial F-test on an effective sample count
tells whether it is more than chance.

The noise an effect is tested against is what remains after ALL signatures of the domain are
fitted at once (so the structure of a second hidden effect does not count as noise). Residuals
of a 1 kHz record are strongly correlated from sample to sample, so n samples carry far fewer
than n independent observations: with the lag-1 autocorrelation rho of that remaining residual,
an AR(1) process has `n_eff = n (1 - rho) / (1 + rho)` (Bartlett's correction), and projecting
such noise onto p regressors gives about (n / n_eff) times the white-noise energy. Hence
`F = (ESS / p) * n_eff / RSS_all` against F(p, n_eff - p_all). An effect counts as found only if
the test rejects at `ALPHA` *and* it explains at least `MIN_EXPLAINED` of the residual, so a huge
record cannot make a negligible effect significant.

Support. Some signatures live on part of the record only: a force held at rest on the samples
at standstill (a few per cent of a machining record), an effect of acceleration on the
accelerating phases. Over the whole record their share is diluted by residual they could never
explain (a model error while moving), and the noise they are tested against is that of other
samples. So both the share and the test are taken on the signature's support (the samples where
one of its regressors reaches SUPPORT_LEVEL of its peak): the share of the support's residual
energy, the noise and its effective samples from the all-signature residual there. For a
signature that lives everywhere (a constant, the direction of motion) nothing changes. A support
of fewer than MIN_SUPPORT_N_EFF effective samples gives no noise level of its own and is not
tested, unless it holds nearly all of the record's (RECORD_SHARE): a smooth record's few are
then the record's limit, not the support's (`supported`).

Dominant. The F-test's effective samples come from the lag-1 autocorrelation, which a smooth
position residual (1 kHz samples of a micrometre model error) drives to a handful: a lead error
whose signature explains 74 % of the position residual left p = 0.009 and was never fitted. A
signature that explains at least DOMINANT of its residual (on its support) is therefore fitted
too (`worth_fitting`), and the simulation's likelihood-ratio test (analysis.significance, whose
dominant-channel rule asks the same share of one channel) decides whether it is kept. The
noise is what remains after every signature of the domain, those not proposed again this round
(tried, or found already) too: their structure is no noise.

Beyond the effort's rate. A drive whose current loop lags its command by T (every real one,
and the synthetic truth's) records a command that leads the twin's by T dF/dt: on a
jerk-limited start or stop that is m T j while the speed is still low, a hump of the direction
of motion that a Stribeck law of a few mm/s fits (about 1 N on the EMPS records of the #30
planner). So an effort-domain effect's share is taken beyond the rate of the twin's effort
(projected out first, Frisch-Waugh, as the alignment's constant is on the position): what the
drive's own fast dynamics, or a sub-tick delay, would explain is no evidence for it. The effects
whose signature is that rate (a delay of the effort) are ranked on the residual as it is.

A missing force also moves the following error through the closed loop, so before
position-domain effects are ranked, the part of the position residual that the effort residual
explains (through a low-pass, the loop's disturbance compliance) is removed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps
from scipy import stats

from feed_twin.analysis.effects import LIBRARY, Effect, Motion
from feed_twin.analysis.significance import ALPHA, DOMINANT, MIN_EXPLAINED
from feed_twin.plant.effect_api import effort_rate

RATE = "effort_rate"  # the key of the effort's rate in a signature (plant.effect_api)
SUPPORT_LEVEL = 1e-2  # a regressor this small against its peak carries 1e-4 of its energy
# A support with fewer effective samples than this cannot give its own noise level: a few
# neighbouring samples of a smooth residual fit any regressor there almost exactly.
MIN_SUPPORT_N_EFF = 10.0
# ... unless it holds this share of the record's own effective samples: then it is the record
# (a screw's heating grows from the first motion on, all but the first rest), and the record's
# count is the limit, as for a signature that lives everywhere, not the support's
RECORD_SHARE = 0.9
# A variant whose signature peaks this far below the effect's largest variant vanishes on the
# record: its weight would be the size of something the record never shows.
VANISHING = 1e-6


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
    domain: str = ""  # the residual ranked ("": the effect's own domain)
    searched: int = 1  # variants the best one was chosen from (p_value is corrected for them)
    # the samples the signature lives on (None: all) and the share of the residual energy there
    # that it explains (the whole record's share where it lives everywhere)
    support: np.ndarray | None = None
    support_fraction: float = 0.0
    # how far the regressors' weighted terms cancel each other (1: they do not): near-collinear
    # regressors fit with huge opposite weights whose sum is small, so the weights mean nothing
    cancellation: float = 1.0
    # newtons at the table per unit of the residual ranked: the weights of an effort in amperes
    # (or newton metres) are not forces (1 A is K_t 2 pi / lead = 1194 N on axis_default)
    force_per_unit: float = 1.0
    # the effective samples of the whole record's residual after all signatures (its domain's)
    record_n_eff: float = math.inf

    @property
    def name(self) -> str:
        return self.effect.name

    @property
    def worth_fitting(self) -> bool:
        """Significant, or explaining at least DOMINANT of its residual where it lives: then
        the simulation's test decides (module docstring, "Dominant")."""
        return self.significant or self.dominant

    @property
    def dominant(self) -> bool:
        return self.support_fraction >= DOMINANT and self.support_counts

    @property
    def support_counts(self) -> bool:
        """Its support can give its own noise level (module docstring, "Support")."""
        return supported(self.support, self.n_eff, self.record_n_eff)

    def force(self, regressor: str) -> float:
        """The weight of `regressor` as a force at the table [N per unit of the regressor]."""
        return self.coefficients.get(regressor, 0.0) * self.force_per_unit

    @property
    def residual_domain(self) -> str:
        return self.domain or self.effect.domain


def _effective_samples(e: np.ndarray) -> float:
    """Bartlett's AR(1) count (module docstring): conservative for smooth residuals, which
    keeps the model error of a clean record (a lag the twin lacks) from passing as an effect;
    the simulation's test (analysis.significance) then uses the integrated time."""
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


test_regressors.__test__ = False  # pyright: ignore[reportFunctionMemberAccess] - pytest's mark: a library function, not a test


def domain_of(effect: Effect, domains: set[str]) -> str | None:
    """The residual an effect is ranked on: its own domain, else its fallback, else None."""
    if effect.domain in domains:
        return effect.domain
    if effect.fallback is not None and effect.fallback in domains:
        return effect.fallback
    return None


def available(effect: Effect, motion: Motion, domains: set[str]) -> bool:
    if domain_of(effect, domains) is None:
        return False
    return all(getattr(motion, need) is not None for need in effect.needs)


def _domain_residuals(
    motion: Motion,
    offset: np.ndarray,
    *,
    effort_residual: np.ndarray | None,
    position_residual: np.ndarray | None,
    loop_stiffness: float | None,
    voltage_residual: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """The residual each domain's effects are ranked on (see `rank`): the position residual
    without its effort-driven part; a record without effort ranks forces on K * position."""
    if effort_residual is None and position_residual is not None and loop_stiffness:
        effort_residual = loop_stiffness * np.asarray(position_residual, dtype=float)
        position_residual = None
    residual_of: dict[str, np.ndarray] = {}
    if effort_residual is not None:
        residual_of["effort"] = np.asarray(effort_residual, dtype=float)
    if position_residual is not None:
        rp = np.asarray(position_residual, dtype=float)
        if effort_residual is not None:
            coupled = {"effort_residual": _lowpass(residual_of["effort"], motion)}
            _, _, _, _, coef = test_regressors(rp, coupled, offset)
            rp = rp - coef["effort_residual"] * coupled["effort_residual"]
        residual_of["position"] = rp
    if voltage_residual is not None:
        residual_of["voltage"] = np.asarray(voltage_residual, dtype=float)
    return residual_of


def rank(
    motion: Motion,
    *,
    effort_residual: np.ndarray | None,
    position_residual: np.ndarray | None,
    exclude: tuple[str, ...] = (),
    loop_stiffness: float | None = None,
    voltage_residual: np.ndarray | None = None,
) -> list[Candidate]:
    """Rank the library's effects on the residuals, most explaining first.

    Effort-domain effects are ranked on the effort residual, position-domain effects on the
    position residual with the effort-driven part removed (see the module docstring),
    voltage-domain effects on the q-voltage residual [V] (or their fallback domain). A record
    without effort (a scope that logged positions only) ranks the effort-domain effects on
    `loop_stiffness * position residual` [N/m * m]: a stiff position loop turns a missing force
    d into a following-error change d / K, so that is the force the twin lacks.
    """
    # a constant position offset belongs to the alignment, not to any effect
    offset = np.ones_like(motion.t_s)
    residual_of = _domain_residuals(
        motion,
        offset,
        effort_residual=effort_residual,
        position_residual=position_residual,
        loop_stiffness=loop_stiffness,
        voltage_residual=voltage_residual,
    )
    domains = set(residual_of)
    best_of: list[tuple[Effect, str, dict[str, np.ndarray], tuple, int, str]] = []
    for effect in LIBRARY:
        if not available(effect, motion, domains):
            continue
        domain = domain_of(effect, domains)
        assert domain is not None
        r = residual_of[domain]
        nuisance = nuisance_of(effect, domain, motion, offset)
        variants = effect.variants(motion)
        if not variants:
            continue  # the record holds none of its evidence (Effect.choices said so)
        signatures = [(label, sig(motion)) for label, sig in variants]
        peaks = [_peak(regs) for _, regs in signatures]
        best = None
        for (label, regs), peak in zip(signatures, peaks, strict=True):
            if peak < VANISHING * max(peaks):
                continue  # not observed on this record (a Stribeck speed far below its speeds)
            result = test_regressors(r, regs, nuisance)
            if best is None or result[0] > best[2][0]:
                best = (label, regs, result)
        assert best is not None
        best_of.append((effect, best[0], best[1], best[2], len(variants), domain))
    # the position's lag and its curvature (a trace window's over [t - w, t]) are no noise
    # either: trace_window, ranked on the position before, brought them into its noise, and
    # ranked on the effort without them a backlash at 41 % of the position residual was no
    # longer significant (the truth machine's Coulomb + backlash)
    lag = np.column_stack([offset, motion.v_m_s, motion.a_m_s2])
    noise = {
        d: _noise_level(
            residual_of[d], [b for b in best_of if b[5] == d], lag if d == "position" else None
        )
        for d in domains
    }
    full_rank = {d: _rank_of(noise[d][1]) for d in domains}
    out: list[Candidate] = []
    for effect, label, regs, result, n_variants, domain in best_of:
        if effect.name in exclude:
            continue  # its structure is no noise (noise above), but it is not proposed again
        explained, _, _, _, coef = result
        r = _projected(residual_of[domain], nuisance_of(effect, domain, motion, offset))
        e_all, Z_all = noise[domain]
        p = len(regs)
        ess = explained * float(np.dot(r, r))
        support = signature_support(regs)
        on = slice(None) if support is None else support
        # see the module docstring: the noise level and its effective sample count come from
        # the residual of all signatures together, so another effect's structure is not noise;
        # both are taken where the signature lives
        rss_full = float(np.dot(e_all[on], e_all[on]))
        n_eff = _effective_samples(e_all[on])
        f_stat = (ess / p) * n_eff / rss_full if rss_full > 0 else math.inf
        # the parameters of all signatures that act on the support
        if Z_all is None:
            p_full = 0
        elif support is None:
            p_full = full_rank[domain]
        else:
            p_full = int(np.linalg.matrix_rank(Z_all[support]))
        dof = max(n_eff - p_full, 1.0)
        p_value = float(stats.f.sf(f_stat, p, dof)) if math.isfinite(f_stat) else 0.0
        # the variant search is one more free parameter, which the F-test's p does not see;
        # Bonferroni over the variants keeps the false-alarm rate at ALPHA
        p_adj = min(1.0, p_value * n_variants)
        energy_on = float(np.dot(r[on], r[on]))
        on_support = min(1.0, ess / energy_on) if energy_on > 0 else 0.0
        record_n_eff = _effective_samples(e_all)
        enough = supported(support, n_eff, record_n_eff)
        out.append(
            Candidate(
                effect=effect,
                variant=label,
                explained_fraction=explained,
                f_statistic=f_stat,
                p_value=p_adj,
                n_eff=n_eff,
                coefficients=coef,
                significant=p_adj < ALPHA and on_support >= MIN_EXPLAINED and enough,
                domain=domain,
                searched=n_variants,
                support=support,
                support_fraction=on_support,
                cancellation=cancellation(regs, coef),
                record_n_eff=record_n_eff,
            )
        )
    out.sort(key=lambda c: (c.worth_fitting, c.explained_fraction), reverse=True)
    return out


def supported(support: np.ndarray | None, n_eff: float, record_n_eff: float) -> bool:
    """A signature's support carries enough effective samples to be tested on its own: at
    least MIN_SUPPORT_N_EFF, or RECORD_SHARE of the whole record's (a support that is nearly
    all of a smooth record is judged as the record is: the thermal growth of a screw, 99 % of
    the samples, 89 % of the position residual, had 9.9 where the record had 10.0 and was
    never fitted). Everywhere (None) it is the record's."""
    if support is None:
        return True
    return n_eff >= min(MIN_SUPPORT_N_EFF, RECORD_SHARE * record_n_eff)


def nuisance_of(
    effect: Effect, domain: str, motion: Motion, offset: np.ndarray
) -> np.ndarray | None:
    """The columns an effect's share is taken beyond (module docstring): a constant on the
    position (the alignment's), the rate of the twin's effort on the effort (the drive's own
    fast dynamics), none for an effect whose signature is that rate."""
    if domain == "position":
        return offset
    if domain != "effort" or motion.effort_sim is None:
        return None
    if any(key == RATE for key in _signature_keys(effect, motion)):
        return None
    return effort_rate(motion)[RATE]


def _signature_keys(effect: Effect, motion: Motion) -> set[str]:
    return {key for _, sig in effect.variants(motion)[:1] for key in sig(motion)}


def _projected(r: np.ndarray, nuisance: np.ndarray | None) -> np.ndarray:
    if nuisance is None:
        return r
    q, _ = np.linalg.qr(nuisance.reshape(len(r), -1))
    return r - q @ (q.T @ r)


def cancellation(regressors: dict[str, np.ndarray], coefficients: dict[str, float]) -> float:
    """max |terms| summed over max |their sum| (1 for one regressor, inf for a zero fit)."""
    terms = np.array([coefficients[k] * np.asarray(z, dtype=float) for k, z in regressors.items()])
    total = float(np.max(np.abs(terms.sum(axis=0)), initial=0.0))
    spread = float(np.max(np.abs(terms).sum(axis=0), initial=0.0))
    if spread == 0.0:
        return 1.0
    return spread / total if total > 0.0 else math.inf


def _peak(regressors: dict[str, np.ndarray]) -> float:
    return max(
        float(np.max(np.abs(np.asarray(z, dtype=float)), initial=0.0)) for z in regressors.values()
    )


def _rank_of(Z: np.ndarray | None) -> int:
    return 0 if Z is None else int(np.linalg.matrix_rank(Z))


def signature_support(regressors: dict[str, np.ndarray]) -> np.ndarray | None:
    """The samples where one of the regressors reaches SUPPORT_LEVEL of its peak; None when
    that is every sample (the signature lives on the whole record)."""
    on = np.zeros(len(next(iter(regressors.values()))), dtype=bool)
    for z in regressors.values():
        size = np.abs(np.asarray(z, dtype=float))
        peak = float(size.max(initial=0.0))
        if peak > 0.0:
            on |= size >= SUPPORT_LEVEL * peak
    return None if on.all() or not on.any() else on


def _noise_level(r: np.ndarray, entries: list, nuisance: np.ndarray | None):
    """(residual, regressors scaled to unit norm) of r after all the domain's signatures at
    once; no regressors: (r, None)."""
    columns = [np.asarray(v, dtype=float) for e in entries for v in e[2].values()]
    if nuisance is not None:
        columns.append(nuisance)
    if not columns:
        return r, None
    Z = np.column_stack(columns)
    scale = np.linalg.norm(Z, axis=0)
    scale[scale == 0.0] = 1.0
    Z = Z / scale
    coef, *_ = np.linalg.lstsq(Z, r, rcond=None)
    return r - Z @ coef, Z


def _lowpass(r: np.ndarray, motion: Motion) -> np.ndarray:
    h = float((motion.t_s[-1] - motion.t_s[0]) / (len(motion.t_s) - 1))
    window = max(5, int(round(0.02 / h)) | 1)
    return np.asarray(sps.savgol_filter(r, window, 1))


def evidence(candidate: Candidate, unit: str) -> str:
    """The finding in plain machine-tool words, with the numbers behind it."""
    c = candidate
    variant = f" ({c.variant})" if c.variant else ""
    coefs = ", ".join(f"{k} {v:+.4g}" for k, v in c.coefficients.items())
    verdict = "significant" if c.significant else "not significant"
    return (
        f"{c.effect.words}{variant}: its signature explains "
        f"{100 * c.explained_fraction:.1f} % of the {c.residual_domain} residual "
        f"(F = {c.f_statistic:.3g} on about {c.n_eff:.0f} independent samples, "
        f"p = {c.p_value:.2g}, {verdict}); least-squares weights {coefs} [{unit}]"
    )
