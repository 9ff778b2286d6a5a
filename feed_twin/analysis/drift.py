"""A parameter that changes over the record: detected with a drift term, named with its rate.

A parameter theta_k that drifts linearly, theta_k(t) = theta_k + rho_k (t - t_mid), changes the
normalised residual by about S_k(t) rho_k (t - t_mid), S_k its sensitivity column
(analysis.uncertainty: the derivative of the residual by a constant change, which a slow drift
follows sample by sample). So the drift's signature is the sensitivity column weighted by time,
and it is tested as every effect is: the residual with every parameter's constant correction
against the residual with the drift term too, by the likelihood-ratio test of
analysis.significance (one added parameter, searched over the candidates), and it must be
material: remove DRIFT_EXPLAINED of one channel's residual energy and change the parameter by
MIN_CHANGE of itself over the record. A component's terms may also drift together (a
guide friction whose Coulomb and viscous parts both grow as the lubricant warms): its drift
direction is the sum of its parameters' sensitivities times their values, and its rate a share
of each per second. Drifts are added one at a time, strongest first, each
tested on top of those before, so two parameters that mimic each other's drift (a Coulomb
force and a viscous one on a record at one speed) are not both named.

A friction that grows by 30 % over the record is then said as such ("guide.F_c drifts by
+0.22 N/s, +30 % over the record"), not taken for a law of speed that the record cannot hold.
The guides' friction drift is also an effect of the library (friction_drift, plant.guide_friction:
every term times 1 + rate t), which the rounds fit with the other effects, so that the effects
found beside it are fitted to a drifting friction; what this module finds is the drift left
beside the effects found (its rate is a SHAPE: it does not drift itself).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feed_twin.analysis.significance import Verdict, compare
from feed_twin.analysis.uncertainty import Sensitivity

# a drift must remove this share of one channel's residual energy: a smooth model error (a lag
# the model lacks) always correlates a little with time, and its p-value alone names a drift on
# every clean record (a 1 % change of a Coulomb force removing 10 % of a position residual at
# twice the encoder's noise)
DRIFT_EXPLAINED = 0.2
MIN_CHANGE = 0.05  # [1] of the parameter's value over the record
# the laws' shapes (a Stribeck speed, a phase, a period) do not drift; their sizes do: a
# Stribeck speed that "drifted" by 9 % on a clean record took a model error of the loop
# a drift's own rate (plant.guide_friction's friction_drift) does not drift either
SHAPES = ("v_s", "phase", "period", "drift_per_s")


@dataclass(frozen=True, kw_only=True)
class Drift:
    slot: str  # a parameter, or a component whose every term drifts alike ("friction.*")
    value: float  # the parameter's value at the record's middle (1 for a component)
    # [its unit per second] (for a component: a share of each term's value at the record's
    # middle per second)
    rate_per_s: float
    duration_s: float
    verdict: Verdict

    @property
    def change(self) -> float:
        """The change over the record as a share of the value at its start (nan for 0)."""
        start = self.value - 0.5 * self.rate_per_s * self.duration_s
        return self.rate_per_s * self.duration_s / abs(start) if start else float("nan")

    def summary(self) -> str:
        """The drift, its rate and its size over the record, in words."""
        if self.slot.endswith(".*"):
            return (
                f"every term of {self.slot[:-2]} drifts alike, by {100 * self.rate_per_s:+.3g} % "
                f"per second ({100 * self.change:+.0f} % over the {self.duration_s:.3g} s record)"
            )
        start = self.value - 0.5 * self.rate_per_s * self.duration_s
        end = self.value + 0.5 * self.rate_per_s * self.duration_s
        return (
            f"{self.slot} drifts by {self.rate_per_s:+.3g} per second ({100 * self.change:+.0f} % "
            f"over the {self.duration_s:.3g} s record, {start:.4g} -> {end:.4g})"
        )

    def words(self) -> str:
        return f"{self.summary()}; the drift term {self.verdict.words()}"

    def as_dict(self) -> dict[str, object]:
        return {
            "parameter": self.slot,
            "value": self.value,
            "rate_per_s": self.rate_per_s,
            "change_over_record": self.change,
            "explained": self.verdict.explained,
            "p_value": self.verdict.p_value,
            "summary": self.summary(),
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
    candidates = _candidates(s)
    named: list[tuple[str, np.ndarray]] = []
    found: list[Drift] = []
    while len(found) < max_drifts:
        before, _ = _residual(s, [col for _, col in named])
        best = None
        for name, (value, direction) in candidates.items():
            if any(name == n for n, _ in named):
                continue
            column = direction * (times - mid)
            after, coef = _residual(s, [col for _, col in named] + [column])
            verdict = compare(
                _channels(s, before), _channels(s, after), added=1, searched=len(candidates)
            )
            if best is None or verdict.likelihood_ratio > best[1].likelihood_ratio:
                best = (name, verdict, column, float(coef[-1]), value)
        if best is None:
            break
        name, verdict, column, rate, value = best
        drift = Drift(slot=name, value=value, rate_per_s=rate, duration_s=duration, verdict=verdict)
        if not (verdict.significant and material(drift)):
            break
        named.append((name, column))
        found.append(drift)
    return found


def material(drift: Drift) -> bool:
    """A drift worth naming: it removes DRIFT_EXPLAINED of one channel's residual energy, and
    the parameter changes by MIN_CHANGE of itself over the record (a 1 % change that a smooth
    model error half explains is no finding)."""
    explained = max(drift.verdict.explained.values(), default=0.0)
    return explained >= DRIFT_EXPLAINED and abs(drift.change) >= MIN_CHANGE


def _candidates(s: Sensitivity) -> dict[str, tuple[float, np.ndarray]]:
    """Each size parameter's (not a shape's: SHAPES) drift direction (its sensitivity) with
    its value, and each component's with two or more non-zero size parameters: every term
    growing by the same share (the sum of the sensitivities times the values, a relative rate)."""
    sizes = [k for k, name in enumerate(s.names) if not name.endswith(SHAPES)]
    out = {s.names[k]: (float(s.values[k]), s.S[:, k]) for k in sizes}
    groups: dict[str, list[int]] = {}
    for k in sizes:
        name = s.names[k]
        if s.values[k] != 0.0:
            groups.setdefault(name.split(".", 1)[0], []).append(k)
    for comp, members in groups.items():
        if len(members) >= 2:
            out[f"{comp}.*"] = (1.0, s.S[:, members] @ s.values[members])
    return out
