"""The twin's own timing against the machine's: a record delay within one twin tick.

A twin whose loops run at a base period h cannot say where within a tick a drive samples,
computes and applies. Its effort at tick k is the command it applies after k, where a drive's
current sampled at k follows the command of k - 1 (one tick later: every clean record of the
independent truth machine named a 1 ms channel_delay, before the twin stamped a drive's actual
effort so); a drive may follow its setpoints a fraction of a tick earlier or later than the
twin's loops (the truth machine's 0.125 ms lead, 13 um of position, was its trace recording the
command one 8 kHz period stale, since fixed: with it recorded at its stamp the lead is 0 for a
twin at 1, 0.5 or 0.25 ms ticks alike). A delay of the record's own
(analysis.effects' RECORD_EFFECTS) fitted within one tick, |d| <= h, therefore shows the twin's
timing, not the recorder's or the machine's: it stays in the model (the rounds after it rank
what it leaves, and model.yaml keeps it), and the report says it as the twin's alignment, but
it is not named as a missing effect. A delay beyond one tick is the record's, and named.

So is a sensor delay (measurement_delay) of less than one tick, which only the refinement
between whole ticks gives (analysis.trials.refined): the loops reading their position a fraction
of a tick late is where within its tick the drive samples, or a fast lag the twin lacks (a
synthetic truth's 0.2 ms current-loop lag, the EMPS twin at 1 ms ticks, was fitted as a 0.2 ms
sensor delay on a record with nothing hidden). A whole tick or more is a sensor's, and named.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol, TypeVar

from feed_twin.analysis.effects import RECORD_EFFECTS

DELAY_KEY = "delay_s"  # the reported parameter of every record delay (analysis.effects)
# a delay this close to one tick is that tick (the search's steps are fractions of it)
TICK_TOLERANCE = 1e-6


RECORD_NAMES = frozenset(e.name for e in RECORD_EFFECTS)
SENSOR_DELAY = "measurement_delay"  # timing below one whole tick (module docstring)


class _Named(Protocol):
    @property
    def name(self) -> str: ...
    @property
    def parameters(self) -> dict[str, float]: ...


def within_tick(effect: _Named, base_period_s: float) -> bool:
    """Whether a found effect is a record delay within one twin tick, or a sensor delay below
    one (module docstring)."""
    if base_period_s <= 0.0:
        raise ValueError(f"base_period_s = {base_period_s!r}: must be > 0")
    delay = effect.parameters.get(DELAY_KEY)
    if delay is None:
        return False
    if effect.name == SENSOR_DELAY:
        return abs(delay) < base_period_s * (1.0 - TICK_TOLERANCE)
    if effect.name not in RECORD_NAMES:
        return False
    return abs(delay) <= base_period_s * (1.0 + TICK_TOLERANCE)


T = TypeVar("T", bound=_Named)


def split_timing(found: Iterable[T], base_period_s: float) -> tuple[list[T], list[T]]:
    """(the effects named, the record delays within one tick: the twin's alignment)."""
    named, timing = [], []
    for f in found:
        (timing if within_tick(f, base_period_s) else named).append(f)
    return named, timing


def timing_line(effect: _Named, base_period_s: float) -> str:
    """What the report says of a delay within one tick: the twin's alignment, kept."""
    delay = effect.parameters[DELAY_KEY]
    return (
        f"the twin's timing against the machine: {effect.name} {delay * 1e3:+.4g} ms, within "
        f"one {base_period_s * 1e3:.4g} ms tick of the twin's loops (where within its tick a "
        "drive samples and acts, which a twin at this rate cannot say), kept in the model "
        "as its alignment, not named as a missing effect"
    )
