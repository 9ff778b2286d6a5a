"""Channel weights and the test an added effect must pass, made to hold on real records.

Weights. The fit's cost sums the squared residuals of up to three channels (effort, position,
q-voltage), each divided by its noise level sigma_c. With the sigma_c unknown, the maximum-
likelihood estimate of each is the RMS of that channel's residual at the current model (the
concentrated likelihood is sum_c n_c/2 ln RSS_c, whose gradient weighs channel c by 1/RSS_c),
so the weights are estimated again from the current model before every round, floored by the
channel's own sample noise (`sample_noise`): what no model can remove. Weights fixed at the
nominal model's residual, as before, let a channel that one large effect explained (the current
of a vertical axis, once the weight is found) carry 1 % of the cost, and the noise of another
channel then decided the rest.

Test. An effect with `added` free parameters, found by a search over `searched` alternatives
(cogging orders, Stribeck speeds, delays, the rivals of one round), is kept when the likelihood
ratio
    LR = sum_c n_eff,c ln(RSS_c,before / RSS_c,after)
exceeds the chi^2(added) quantile at ALPHA / searched (Bonferroni: the best of m alternatives
is as likely to pass by chance as any of m tests), and it removes at least MIN_EXPLAINED of one
channel's residual energy (so that a huge record cannot make a negligible effect count). An
effect that halves one channel's residual RMS removes 75 % of that channel's energy: no other
channel can veto it, unless that one gets worse by as much in likelihood. An effect named from
its signature in one channel (`own`: the residual the ranking found it in) must not make that
channel worse: a drive gain named on the effort that the fit bends to explain the position while
the effort gets worse is another effect's evidence (on a vertical axis, the table
held at rest), not its own.

A dominant channel. The sum above weighs each channel by its effective samples: a smooth
position residual (a model error of the loop, far above the encoder's noise) carries a few
dozen, a white effort residual thousands, so an effect that removes 98 % of the position
residual (a lead error, 950x the position's noise) was rejected because its fit, in a model
that is not the machine, made the effort 14 % worse. So an effect that fails the joint test
still counts when it removes at least DOMINANT of one channel's residual energy, passes the test
on that channel alone (Bonferroni over the channels), and removes more than it adds over all
channels with each channel's energy in units of its own noise level at the model before (the
fit's weights: sum_c explained_c > 0), and does not worsen the channel it was named in.

Support. An effect that lives on part of the record (a force held at rest: the samples at
standstill) is tested with two noise levels per channel, one on its support and one on the
rest of the record: the concentrated likelihood then sums n_eff ln(RSS_before / RSS_after)
over both groups, so the noise it is measured against is the noise where it acts (not a model
error while moving, which no holding force can touch), while what it costs elsewhere still
counts. Its share of a channel's residual energy is taken on the support.

Effective samples. Residuals of filtered records are correlated over many samples; n samples
then carry n / tau independent observations, tau the integrated autocorrelation time
1 + 2 sum_k rho_k (summed up to Sokal's window, the first M >= 5 tau(M)): the spectrum at low
frequencies, where the signatures live, over the variance. The AR(1) value
(1 + rho_1) / (1 - rho_1), which the ranking's screen keeps on purpose (analysis.ranking), is
3.5 times too large for the noise of a second-order trace filter
(tests/test_analysis_significance.py): here it would make real effects of filtered records
look like chance.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps
from scipy import stats

ALPHA = 1e-3  # false-alarm probability of one test
DOMINANT = 0.5  # share of one channel's residual energy that lets that channel decide alone
MIN_EXPLAINED = 0.05  # share of one channel's residual energy an effect must remove
NOISE_WINDOW = 7  # samples of the local cubic that sample_noise removes
SOKAL_C = 5.0  # window factor of the integrated autocorrelation time


def sample_noise(y: np.ndarray) -> float:
    """Standard deviation of the sample-to-sample noise of a recorded signal.

    The residual of a local cubic over NOISE_WINDOW samples keeps white noise with the variance
    sigma^2 (1 - s_0), s_0 the filter's centre weight (the filter is a projection), and keeps
    little of a smooth motion; its median absolute value makes one glitch irrelevant.
    """
    y = np.asarray(y, dtype=float)
    if len(y) < 2 * NOISE_WINDOW:
        return 0.0
    smooth = sps.savgol_filter(y, NOISE_WINDOW, 3)
    centre = sps.savgol_coeffs(NOISE_WINDOW, 3)[NOISE_WINDOW // 2]
    mad = float(np.median(np.abs(y - smooth)))
    return 1.4826 * mad / math.sqrt(1.0 - centre)


def effective_samples(e: np.ndarray) -> float:
    """Independent observations behind n correlated residual samples (module docstring)."""
    e = np.asarray(e, dtype=float)
    e = e - e.mean()
    n = len(e)
    energy = float(np.dot(e, e))
    if n < 3 or energy == 0.0:
        return float(n)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(e, size)
    acf = np.fft.irfft(spectrum * np.conj(spectrum), size)[:n] / energy
    tau_sum = 1.0 + 2.0 * np.cumsum(acf[1:])
    lags = np.arange(1, n)
    inside = lags < SOKAL_C * tau_sum
    window = int(np.argmin(inside)) if not inside.all() else n - 2
    return n / max(float(tau_sum[window]), 1.0)


@dataclass(frozen=True, kw_only=True)
class Verdict:
    """Whether one model explains the record significantly better than another."""

    likelihood_ratio: float
    p_value: float  # after the correction for the search
    explained: dict[str, float]  # channel -> share of its residual energy removed
    significant: bool
    own: str = ""  # the channel the effect was named in ("" if not given)
    # the channel whose own test decided (module docstring), "" when all channels' did
    dominant: str = ""

    @property
    def worsens_own(self) -> bool:
        """The effect makes the residual it was named in worse."""
        return self.explained.get(self.own, 0.0) < 0.0

    @property
    def best_channel(self) -> str:
        return max(self.explained, key=self.explained.__getitem__)

    def words(self) -> str:
        from feed_twin.analysis.wording import shares

        worse = f", worse in the {self.own} residual it was named in" if self.worsens_own else ""
        on = f" in the {self.dominant} channel, which it dominates" if self.dominant else ""
        return (
            f"{shares(self.explained)} (LR = {self.likelihood_ratio:.3g}{on}, "
            f"p = {self.p_value:.2g}){worse}"
        )


def compare(
    before: Mapping[str, np.ndarray],
    after: Mapping[str, np.ndarray],
    *,
    added: int,
    searched: int = 1,
    own: str = "",
    support: np.ndarray | None = None,
) -> Verdict:
    """The likelihood-ratio test of `after` (added free parameters) against `before`.

    Both map a channel name to its residual (measured minus model) on one time base; `own` is
    the channel the effect was named in, which it must not make worse; `support` (a mask on
    that time base) the samples the effect lives on (module docstring), None for all.
    """
    if added < 1 or searched < 1:
        raise ValueError(f"added = {added!r}, searched = {searched!r}: both must be >= 1")
    groups = [slice(None)] if support is None else [support, ~support]
    lr_of: dict[str, float] = {}
    explained: dict[str, float] = {}
    for name, r_after in after.items():
        for group in groups:
            b, a = before[name][group], r_after[group]
            rss_before, rss_after = float(np.dot(b, b)), float(np.dot(a, a))
            if rss_before <= 0.0:
                continue
            if group is groups[0]:
                explained[name] = 1.0 - rss_after / rss_before
            lr = effective_samples(a) * math.log(rss_before / max(rss_after, 1e-300))
            lr_of[name] = lr_of.get(name, 0.0) + lr
    lr = sum(lr_of.values())
    p = _p_value(lr, added, searched)
    best = max(explained.values(), default=0.0)
    verdict = Verdict(
        likelihood_ratio=lr, p_value=p, explained=explained, significant=False, own=own
    )
    significant = p < ALPHA and best >= MIN_EXPLAINED and not verdict.worsens_own
    if not significant and explained and not verdict.worsens_own:
        # the dominant channel's own test (module docstring), Bonferroni over the channels
        dominant = verdict.best_channel
        p_dominant = _p_value(lr_of.get(dominant, 0.0), added, searched * len(explained))
        net = sum(explained.values())  # each channel's energy in units of its own noise
        if best >= DOMINANT and p_dominant < ALPHA and net > 0.0:
            verdict = dataclasses.replace(
                verdict, likelihood_ratio=lr_of[dominant], p_value=p_dominant, dominant=dominant
            )
            significant = True
    return dataclasses.replace(verdict, significant=significant)


def _p_value(lr: float, added: int, searched: int) -> float:
    p = float(stats.chi2.sf(lr, added)) if lr > 0.0 else 1.0
    return min(1.0, p * searched)
