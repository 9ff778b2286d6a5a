"""Forced breaks of chains: where a long chain of gentle corners may be cut for look-ahead.

The streaming planner commits a window up to a corner blended alone (`planner`); a CAM curve of
thousands of gentle corners has none, so near every `spacing`-th node (global index) a forced
break is blended alone. A forced break squeezes the blends next to it and so slows the curve
around it. So it is placed where the path turns least within an eighth of the spacing of that
node (an inflection, a straight piece) where that is much less than at the node itself, and
only where nothing else breaks the chain nearby: no natural break (a stop, a node with events
or dwells, a clearly sharp corner) within a quarter of the spacing. Then a window of 2
spacings from its first uncommitted node always holds a natural or forced break in about its
first half. The rest of a program planned at once (the last window) needs no new break.

Each candidate is decided once, in the first window that lists it, and keeps that decision,
so the speeds a window commits stay reachable. Where that window does not list its whole
neighbourhood (its last nodes excluded, where the stop at its end is not the program's), the
break stays on the candidate node. One exception: the planner drops forced breaks that lie
wholly in the committed part (`planner._commit_break_only`); where that makes a later
window's limits tighter than the committed speed allows, that window plans again with the
committed window's breaks (and, if needed, its stop; `planner._as_decided`).

The last window commits the program's rest: it drops the breaks decided beyond the motion a
filter window at its first node reaches (`beyond`). Without them its constraints only relax
(wider blends, no squeezed neighbours, no holds), and the bodies whose limits the committed
motion's samples share (within that reach, the erosion's) are planned as the committed window
planned them.
"""

from __future__ import annotations

import numpy as np

from feed_twin.gcode.plan_blends import SHARP_CORNER

# A natural break must stay one whatever the smoothing of its neighbours does (a few um on
# moves of 0.1 mm and more turn a direction by a few 1e-2): clearly sharper than SHARP_CORNER.
NATURAL_SHARPNESS = 2.0
# A forced break moves off its candidate node only to where the path turns this much less (on
# a curve of even curvature the breaks stay evenly spaced, and so do the committed chunks).
SHIFT_GAIN = 0.5


def forced_breaks(
    P: np.ndarray,
    natural: np.ndarray,
    *,
    g0: int,
    spacing: int,
    stable: int,
    final: bool,
    decided: dict[int, int],
    beyond: np.ndarray | None = None,
) -> np.ndarray:
    """Which listed nodes (n+1) are forced breaks; new decisions are added to `decided`
    (global candidate node -> the global node of its forced break, -1 for none).

    `P` (n+1, n_axes) are the listed vertices, node i is global node g0 + i; `natural` (n+1)
    marks the stops and nodes with events or dwells the program puts there; nodes above
    `stable` are not yet final (the window's end); `final`: the window plans the program's
    rest at once, and then the breaks decided at the listed nodes `beyond` (n+1) marks are
    dropped.
    """
    n = len(P) - 1
    forced = np.zeros(n + 1, dtype=bool)
    index = np.arange(n + 1)
    candidates = [int(i) for i in index[(index + g0) % spacing == 0] if int(i) + g0 not in decided]
    if candidates and not final:
        _decide(P, natural, candidates, g0=g0, spacing=spacing, stable=stable, decided=decided)
    # Breaks decided, of candidates listed or not (just before the first listed node).
    at = np.array([node for node in decided.values() if g0 <= node <= g0 + n], dtype=int)
    forced[at - g0] = True
    if final and beyond is not None:
        forced &= ~beyond
    return forced


def _decide(
    P: np.ndarray,
    natural: np.ndarray,
    candidates: list[int],
    *,
    g0: int,
    spacing: int,
    stable: int,
    decided: dict[int, int],
) -> None:
    """Decide the new candidates (listed indices) into `decided` (see `forced_breaks`)."""
    n = len(P) - 1
    delta = np.diff(P, axis=0)
    length = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = delta / length[:, None]
    turn = np.full(n + 1, np.inf)
    turn[1:n] = np.linalg.norm(u[1:] - u[:-1], axis=1)
    breaks = natural | (turn > NATURAL_SHARPNESS * SHARP_CORNER) & np.isfinite(turn)
    breaks[stable + 1 :] = False
    radius = spacing // 4
    shift = spacing // 8
    for i in candidates:
        key = i + g0
        if i + radius > stable:
            decided[key] = key  # its neighbourhood is not all listed yet: where it is
        elif np.any(breaks[max(i - radius, 0) : i + radius + 1]):
            decided[key] = -1
        else:
            lo = max(i - shift, 1)
            best = lo + int(np.argmin(turn[lo : i + shift + 1]))
            decided[key] = g0 + (best if turn[best] < SHIFT_GAIN * turn[i] else i)
