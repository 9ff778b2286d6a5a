"""Planner stage 0 (jerk profile): the vertices of CAM polylines smoothed within the tolerance.

CAM programs approximate curves by short moves whose vertices carry the CAM system's chord
error and the G-code's rounding (0.1 um at four decimals). On moves of 0.1-0.2 mm that rounding
alone changes the direction change from node to node by tens of percent: the blended path turns
it into steps of curvature, x''' of 1e5 1/m^2 where the curve itself has 1e4, and the jerk
limit caps the feed by them (`plan_blends.zone_coefficients`). Controllers smooth such code
within a tolerance before they plan it (Sinumerik COMPCAD and G642, Heidenhain ADP, LinuxCNC's
G64 Q merges nearly collinear moves); this is the smallest step in that direction:

- a vertex is *movable* where the path turns gently there (|u_out - u_in| <= SHARP_CORNER), both
  its moves are feed moves of at most SMOOTH_MOVE_M that are not arc chords, and it is not a
  stop, a node with events or dwells, or a forced break of chains;
- each movable vertex is replaced by the value at it of the least-squares quadratic (in the
  polyline's arc length) through itself and up to SMOOTH_REACH vertices on each side, a run
  stopping at (and including) the first vertex that is not movable: a local polynomial
  (Savitzky-Golay) filter, which keeps straight lines exactly and circles to a fraction of a
  micrometre, and removes the rounding noise;
- it moves by at most SMOOTH_SHARE of its tolerance (G64 P): a segment between displaced
  vertices stays within the larger displacement of the programmed one, and the blends of the
  nodes around take the rest of the tolerance (`blend_tolerance`).

Vertices that are not movable stay where the program puts them: sharp corners, stops, arcs,
long moves. The planner freezes the smoothed vertices it commits (`planner`), so a window that
starts from committed motion sees the same geometry.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from feed_twin.gcode.plan_blends import SHARP_CORNER

SMOOTH_REACH = 4  # vertices on each side that a vertex's quadratic is fitted to
SMOOTH_SHARE = 0.25  # share of the tolerance a vertex may move; its blends keep the rest
SMOOTH_MOVE_M = 2e-3  # [m] moves longer than this are programmed geometry, not CAM points


def movable_vertices(
    P: np.ndarray,
    rapid: np.ndarray,
    arc: np.ndarray,
    fixed: np.ndarray,
) -> np.ndarray:
    """Which vertices (n+1) of the polyline `P` (n+1, n_axes) may move: see the module
    docstring; `rapid`, `arc` (n) flag the moves, `fixed` (n+1) the vertices the program or
    the planner pins (stops, events, forced breaks, frozen vertices)."""
    n = len(P) - 1
    movable = np.zeros(n + 1, dtype=bool)
    if n < 2:
        return movable
    delta = np.diff(P, axis=0)
    L = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = delta / L[:, None]
    turn = np.linalg.norm(u[1:] - u[:-1], axis=1)
    cam = ~rapid & ~arc & (L <= SMOOTH_MOVE_M) & (L > 0.0)
    movable[1:n] = cam[:-1] & cam[1:] & (turn <= SHARP_CORNER)
    return movable & ~fixed


@njit(cache=True)
def smooth_vertices(P: np.ndarray, movable: np.ndarray, limit: np.ndarray, reach: int):
    """The vertices with each movable one replaced by its local quadratic's value, moved by
    at most limit[j] [m] (see the module docstring)."""
    n1, na = P.shape
    S = np.zeros(n1)
    for i in range(1, n1):
        S[i] = S[i - 1] + np.sqrt(np.sum((P[i] - P[i - 1]) ** 2))
    out = P.copy()
    m = np.empty(5)  # sums of t^k over the run
    r = np.empty((3, na))  # sums of t^k P
    for j in range(n1):
        if not movable[j]:
            continue
        lo = j - 1
        while lo > 0 and j - lo < reach and movable[lo]:
            lo -= 1
        hi = j + 1
        while hi < n1 - 1 and hi - j < reach and movable[hi]:
            hi += 1
        # The least-squares quadratic c0 + c1 t + c2 t^2 through P[lo..hi] in
        # t = (S - S[j]) / (S[hi] - S[lo]); its value at j is c0 (Cramer's rule on the
        # normal equations, whose matrix [[m0 m1 m2] [m1 m2 m3] [m2 m3 m4]] is symmetric).
        scale = S[hi] - S[lo]
        m[:] = 0.0
        r[:, :] = 0.0
        for i in range(lo, hi + 1):
            t = (S[i] - S[j]) / scale
            t2 = t * t
            m[0] += 1.0
            m[1] += t
            m[2] += t2
            m[3] += t2 * t
            m[4] += t2 * t2
            for a in range(na):
                r[0, a] += P[i, a]
                r[1, a] += t * P[i, a]
                r[2, a] += t2 * P[i, a]
        c0 = m[2] * m[4] - m[3] * m[3]
        c1 = m[2] * m[3] - m[1] * m[4]
        c2 = m[1] * m[3] - m[2] * m[2]
        det = m[0] * c0 + m[1] * c1 + m[2] * c2
        size = 0.0
        for a in range(na):
            out[j, a] = (c0 * r[0, a] + c1 * r[1, a] + c2 * r[2, a]) / det - P[j, a]
            size += out[j, a] * out[j, a]
        size = np.sqrt(size)
        keep = limit[j] / size if size > limit[j] else 1.0
        for a in range(na):
            out[j, a] = P[j, a] + keep * out[j, a]
    return out


def blend_tolerance(tol: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """Tolerances (n+1) [m] left to the blends: the part SMOOTH_SHARE smoothing does not take,
    at each movable vertex and its neighbours (whose moves it displaces)."""
    near = movable.copy()
    near[1:] |= movable[:-1]
    near[:-1] |= movable[1:]
    return np.where(near, (1.0 - SMOOTH_SHARE) * tol, tol)
