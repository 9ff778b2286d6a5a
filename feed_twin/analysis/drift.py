"""A parameter that changes over the record: detected with a drift term, named with its rate.

A parameter theta_k that drifts linearly, theta_k(t) = theta_k + rho_k (t - t_mid), changes the
normalised residual by about S_k(t) rho_k (t - t_mid), S_k its sensitivity column
(analysis.uncertainty: the derivative of the residual by a constant change, which a slow drift
follows sample by sample). So the drift's signature is the sensitivity column weighted by time,
and it is tested as every effect is: the residual with every parameter's constant correction
against the residual with the drift term too, by the likelihood-ratio test of
analysis.significance (one added parameter, searched over the p parameters, removing at least
MIN_EXPLAINED of one channel's residual). Drifts are added one at a time, strongest first, each
tested on top of those before, so two parameters that mimic each other's drift (a Coulomb
force and a viscous one on a record at one speed) are not both named.

A friction that grows by 30 % over the record is then said as such ("guide.F_c drifts by
+0.22 N/s, +30 % over the record"), not taken for a law of speed that the record cannot hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feed_twin.analysis.significance import MIN_EXPLAINED, Verdict, compare
from feed_twin.analysis.uncertainty import Sensitivity


@dataclass(frozen=True, kw_only=True)
class Drift:
    slot: str
    value: float  # the parameter's value at the record's middle
    rate_per_s: float  # [its unit per second]
    duration_s: float
    verdict: Verdict

    @property
    def change(self) -> float:
        """The change over the record as a share of the value (nan for a value of 0)."""
        return self.rate_per_s * self.duration_s / abs(self.value) if self.value else float("nan")

    def words(self) -> str:
        start = self.value - 0.5 * self.rate_per_s * self.duration_s
        end = self.value + 0.5 * self.rate_per_s * self.duration_s
        return (
            f"{self.slot} drifts by {self.rate_per_s:+.3g} per second ({100 * self.change:+.0f} % "
            f"over the {self.duration_s:.3g} s record, {start:.4g} -> {end:.4g}); the drift term "
            f"{self.verdict.words()}"
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "parameter": self.slot,
            "value": self.value,
            "rate_per_s": self.rate_per_s,
            "change_over_record": self.change,
            "explained": self.verdict.explained,
            "p_value": self.verdict.p_value,
            "words": self.words(),
        }


def _residual(s: Sensitivity, columns: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    A = np.column_stack([s.S, *columns]) if columns else s.S
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0.0] = 1.0
    coef, *_ = np.linalg.lstsq(A / scale, -s.r, rcond=None)
    coef = coef / scale
    return s.r + A @ coef, coef


def _channels(s: Sensitivity, e: np.ndarray) -> dict[str, np.ndarray]:
    return {c: e[rows] for c, rows in s.blocks.items()}


def drifts(s: Sensitivity, *, max_drifts: int = 2) -> list[Drift]:
    """The significant drifts of the free parameters, strongest first (module docstring)."""
    if s.S.shape[1] == 0:
        return []
    times = s.t_s
    mid = 0.5 * (float(times.min()) + float(times.max()))
    duration = float(times.max() - times.min())
    named: list[tuple[int, np.ndarray]] = []
    found: list[Drift] = []
    while len(found) < max_drifts:
        before, _ = _residual(s, [col for _, col in named])
        best = None
        for k in range(len(s.names)):
            if any(k == j for j, _ in named):
                continue
            column = s.S[:, k] * (times - mid)
            after, coef = _residual(s, [col for _, col in named] + [column])
            verdict = compare(
                _channels(s, before), _channels(s, after), added=1, searched=len(s.names)
            )
            if best is None or verdict.likelihood_ratio > best[1].likelihood_ratio:
                best = (k, verdict, column, float(coef[-1]), float(coef[k]))
        if best is None:
            break
        k, verdict, column, rate, offset = best
        if not verdict.significant or max(verdict.explained.values()) < MIN_EXPLAINED:
            break
        named.append((k, column))
        found.append(
            Drift(
                slot=s.names[k],
                value=float(s.values[k]) + offset,
                rate_per_s=rate,
                duration_s=duration,
                verdict=verdict,
            )
        )
    return found
