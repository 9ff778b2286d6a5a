"""The workflow's verdict, and what is left when the library has nothing more to say.

A verdict never says "no significant missing effect" while a channel's residual stays far above
its sample noise (FAR_ABOVE_NOISE times it): that residual is a model error no library effect
explains (a delay of a recorded channel, a lag the model lacks, a law the library does not
have), and the user is told its size and its signature, in the words an engineer would use to
look for it:
- when: the time window (of TIME_WINDOWS) where it is largest, and whether it grows over the
  record;
- where: the phase of the motion (standstill, accelerating, constant speed) that holds most
  of its energy, against the share of the samples there (a residual that lives on the
  accelerations is a dynamic error, one at standstill a holding or a zero);
- what it follows: the motion quantity it is most correlated with (position, speed, its sign,
  acceleration, time), with the correlation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from feed_twin.analysis.locate import direction

FAR_ABOVE_NOISE = 10.0  # a residual RMS this many times its sample noise is not noise
TIME_WINDOWS = 5
ACCELERATING = 0.1  # |a| above this share of its peak: the axis is accelerating


@dataclass(frozen=True, kw_only=True)
class Leftover:
    """One channel's residual at the final model against its sample noise."""

    channel: str
    unit: str
    rms: float
    noise_ratio: float  # rms over the channel's sample noise
    signature: str  # when, where and what it follows, in words

    @property
    def far_above_noise(self) -> bool:
        return self.noise_ratio > FAR_ABOVE_NOISE

    def words(self) -> str:
        return (
            f"{self.channel} residual RMS {self.rms:.3g} {self.unit} = {self.noise_ratio:.3g} x "
            f"its sample noise"
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "channel": self.channel,
            "unit": self.unit,
            "rms": self.rms,
            "noise_ratio": self.noise_ratio,
            "far_above_noise": self.far_above_noise,
            "signature": self.signature,
        }


def signature(r: np.ndarray, t_s: np.ndarray, x_m: np.ndarray, v: np.ndarray, a: np.ndarray):
    """When and where the residual `r` sits and what it follows, in words (module docstring)."""
    energy = r**2
    total = float(energy.sum())
    if total <= 0.0:
        return "it is zero"
    windows = np.array_split(np.arange(len(r)), TIME_WINDOWS)
    rms = [float(np.sqrt(np.mean(energy[w]))) for w in windows]
    k = int(np.argmax(rms))
    span = (float(t_s[windows[k][0]]), float(t_s[windows[k][-1]]))
    when = f"largest at t = {span[0]:.3g}..{span[1]:.3g} s"
    if rms[0] > 0.0 and rms[-1] > 1.5 * rms[0]:
        when += f", growing over the record (RMS x{rms[-1] / rms[0]:.2g} first to last window)"
    moving = direction(v) != 0
    accelerating = moving & (np.abs(a) > ACCELERATING * float(np.max(np.abs(a), initial=0.0)))
    phases = {
        "at standstill": ~moving,
        "while accelerating": accelerating,
        "at constant speed": moving & ~accelerating,
    }
    shares = {
        name: (float(energy[on].sum()) / total, float(np.mean(on))) for name, on in phases.items()
    }
    where = max(shares, key=lambda p: shares[p][0])
    share, samples = shares[where]
    located = f"{100 * share:.0f} % of its energy {where} ({100 * samples:.0f} % of the samples)"
    quantities = {
        "the position": x_m,
        "the speed": v,
        "the direction of motion": np.sign(v),
        "the acceleration": a,
        "time": t_s,
    }
    corr = {name: _correlation(r, q) for name, q in quantities.items()}
    best = max(corr, key=lambda name: abs(corr[name]))
    follows = f"it follows {best} (correlation {corr[best]:+.2f})"
    return f"{when}; {located}; {follows}"


def _correlation(r: np.ndarray, q: np.ndarray) -> float:
    r, q = r - r.mean(), q - q.mean()
    spread = float(np.sqrt(np.dot(r, r) * np.dot(q, q)))
    return float(np.dot(r, q)) / spread if spread > 0.0 else 0.0


def verdict(
    found: list[str],
    unfitted: list[str],
    leftover: list[Leftover],
    drifts: Sequence[str] = (),
    unsearched: Sequence[str] = (),
) -> str:
    """The verdict's sentence: what the model misses, what changed over the record
    (analysis.drift), what is left far above the noise, and then the effects the model could
    not carry and were not searched (analysis.visibility: what is left may be theirs)."""
    text = _verdict(found, unfitted, leftover)
    if drifts:
        text += "; and something changed over the record: " + "; ".join(drifts)
    if unsearched and any(c.far_above_noise for c in leftover):
        # what is left might be theirs: said where a residual far above the noise remains
        text += f"; not searched, the model cannot carry them: {', '.join(unsearched)}"
    return text


def _verdict(found: list[str], unfitted: list[str], leftover: list[Leftover]) -> str:
    large = [c for c in leftover if c.far_above_noise]
    unexplained = (
        "a residual far above the noise remains that no effect of the library explains ("
        + "; ".join(f"{c.words()}: {c.signature}" for c in large)
        + ")"
    )
    if found:
        head = f"the nominal model misses {', '.join(found)}; with them the gap shrinks as shown"
        return f"{head}, but {unexplained}" if large else head
    if unfitted:
        return (
            f"the residual carries the signature of {', '.join(unfitted)}, which could not be "
            "fitted" + (f"; {unexplained}" if large else "")
        )
    if large:
        return "no effect of the library is missing, but " + unexplained
    return (
        "no significant missing effect: no effect of the library explains a significant part "
        "of what is left (" + "; ".join(c.words() for c in leftover) + ")"
    )
