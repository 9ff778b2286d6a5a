"""Figures as the workflow says them: rounded to what they mean, and no percentage of a base
that is nearly zero (a residual that an effect makes worse is said as a ratio, not as
"removes -9567.3 %")."""

from __future__ import annotations

from collections.abc import Mapping

SIGNIFICANT = 4  # significant figures of a fitted value
# below this share a channel's change is "unchanged" (the float noise of a re-simulation)
UNCHANGED = 5e-4


def share(fraction: float, channel: str) -> str:
    """What an effect did to a channel's residual energy: `fraction` = 1 - after / before."""
    if abs(fraction) < UNCHANGED:
        return f"leaves the {channel} residual unchanged"
    if fraction >= 0.0:
        return f"removes {100.0 * fraction:.3g} % of the {channel} residual energy"
    return f"makes the {channel} residual energy {1.0 - fraction:.3g}x larger"


def shares(explained: Mapping[str, float]) -> str:
    """`share` of every channel, joined."""
    return "; ".join(share(v, k) for k, v in explained.items())


def values(params: Mapping[str, float]) -> str:
    """Fitted values to SIGNIFICANT figures: `F_hold_N = 4686`."""
    return ", ".join(f"{k} = {v:.{SIGNIFICANT}g}" for k, v in params.items())


def percent(value: float | None) -> str:
    """A relative error in percent to 3 significant figures, '-' where there is none."""
    return "-" if value is None else f"{value:.3g} %"
