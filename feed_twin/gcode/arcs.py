"""Arc geometry of G2/G3 blocks: centre from R or checked I/J/K, sweep, and chord points.

Pure functions on machine coordinates [m]; `ArcError` carries the reason, and the
interpreter adds the file, line and word.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from feed_twin.gcode.codes import MM

CHORD_SAGITTA_SHARE = 0.75  # largest chord sagitta, as a share of the chord tolerance


class Arc(NamedTuple):
    """The programmed circle (or helix) of a G2/G3 block, shared by all of its chords.

    At the fraction f of the sweep the point is centre + r(f) (cos, sin)(theta0 + f sweep) in
    the plane, r(f) = r_start + (r_end - r_start) f; every other axis moves linearly in f.
    """

    plane_axes: tuple[int, int, int]  # axis indices: first, second and normal axis of the plane
    centre_m: tuple[float, float]  # [m] centre in machine coordinates (first, second axis)
    r_start_m: float  # [m] radius at the start point
    r_end_m: float  # [m] radius at the end point (differs within arc_radius_tolerance_m)
    theta0_rad: float  # [rad] angle of the start point, from the first axis towards the second
    sweep_rad: float  # [rad] signed sweep, > 0 counter-clockwise (G3), full turns included


class ArcError(ValueError):
    """An arc that cannot be drawn as written; the message is the reason."""


Point2 = tuple[float, float]


def centre_from_radius(
    start: Point2, end: Point2, radius: float, *, clockwise: bool, tol: float
) -> Point2:
    """The centre of an R-form arc [m]: left of the chord for a short CCW arc; R < 0: long."""
    (a0, b0), (a1, b1) = start, end
    chord = math.hypot(a1 - a0, b1 - b0)
    if chord <= tol:
        raise ArcError("R-form arc with equal start and end point (a full circle needs I/J/K)")
    half = 0.5 * chord
    if abs(radius) < half - tol:
        raise ArcError(
            f"radius {abs(radius) / MM:.6g} mm is smaller than half the distance "
            f"between start and end ({half / MM:.6g} mm)"
        )
    h = math.sqrt(max(radius * radius - half * half, 0.0))
    side = (1.0 if not clockwise else -1.0) * (1.0 if radius > 0 else -1.0)
    ma, mb = 0.5 * (a0 + a1), 0.5 * (b0 + b1)
    return ma - side * h * (b1 - b0) / chord, mb + side * h * (a1 - a0) / chord


def check_centre(start: Point2, end: Point2, centre: Point2, tol: float) -> None:
    """An I/J/K centre must be off the start point and equally far from start and end."""
    (a0, b0), (a1, b1), (ca, cb) = start, end, centre
    r0 = math.hypot(a0 - ca, b0 - cb)
    r1 = math.hypot(a1 - ca, b1 - cb)
    if r0 <= tol:
        raise ArcError("arc centre coincides with the start point")
    if abs(r0 - r1) > tol:
        raise ArcError(
            f"start radius {r0 / MM:.6g} mm and end radius {r1 / MM:.6g} mm differ by "
            f"{abs(r0 - r1) / MM:.3g} mm (tolerance {tol / MM:.3g} mm)"
        )


def arc_sweep(
    start: Point2,
    end: Point2,
    centre: Point2,
    axes: tuple[int, int, int],
    *,
    clockwise: bool,
    turns: int,
    full_circle_if_closed: bool,
    tol: float,
) -> Arc:
    """The arc from start to end about centre: radii, start angle, signed sweep with turns.

    An I/J/K arc whose end is its start (within tol) is a full circle.
    """
    (a0, b0), (a1, b1), (ca, cb) = start, end, centre
    chord = math.hypot(a1 - a0, b1 - b0)
    r0 = math.hypot(a0 - ca, b0 - cb)
    r1 = math.hypot(a1 - ca, b1 - cb)
    theta0 = math.atan2(b0 - cb, a0 - ca)
    theta1 = math.atan2(b1 - cb, a1 - ca)
    if clockwise:
        sweep = -((theta0 - theta1) % (2.0 * math.pi))
    else:
        sweep = (theta1 - theta0) % (2.0 * math.pi)
    if chord <= tol and full_circle_if_closed or sweep == 0.0:
        sweep = -2.0 * math.pi if clockwise else 2.0 * math.pi
    sweep += math.copysign(2.0 * math.pi * (turns - 1), sweep)
    return Arc(axes, (ca, cb), r0, r1, theta0, sweep)


def chord_points(
    start: list[float], target: list[float], arc: Arc, chord_tolerance: float
) -> list[list[float]]:
    """End points of the chords [m], all axes, the last one `target`.

    The planner's chained blends round each chord vertex inwards by up to 4/3 of the
    sagitta (|dU| w/6 with w up to a chord length: (2/3)(1 + cos(step/4)) sagittas), so
    the chords keep 3/4 of the tolerance and the blended path stays within all of it.
    """
    i1, i2, i_n = arc.plane_axes
    (ca, cb), r0, r1 = arc.centre_m, arc.r_start_m, arc.r_end_m
    theta0, sweep = arc.theta0_rad, arc.sweep_rad
    radius = max(r0, r1)
    eps = CHORD_SAGITTA_SHARE * chord_tolerance
    step = 2.0 * math.acos(1.0 - eps / radius) if eps < radius else math.pi / 2
    n = max(1, math.ceil(abs(sweep) / min(step, math.pi / 2)))
    n0 = start[i_n]
    n1 = target[i_n]
    points: list[list[float]] = []
    for k in range(1, n + 1):
        if k == n:
            point = list(target)
        else:
            f = k / n
            theta = theta0 + sweep * f
            r = r0 + (r1 - r0) * f
            point = list(target)
            point[i1] = ca + r * math.cos(theta)
            point[i2] = cb + r * math.sin(theta)
            point[i_n] = n0 + (n1 - n0) * f
            for j in range(len(start)):
                if j not in (i1, i2, i_n):
                    point[j] = start[j] + (target[j] - start[j]) * f
        points.append(point)
    return points
