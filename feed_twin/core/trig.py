"""Sine and cosine of one angle together, for the Park transforms in the hot loop.

    sincos(theta) = (cos(theta), sin(theta))

The angle is reduced to r = theta - n*pi/2, |r| <= pi/4, with pi/2 split into a 33-bit head,
a 33-bit middle and a tail (Cody and Waite), so that n*head and n*middle are exact for
|n| < 2^20 (|theta| < 1.6e6 rad); beyond that the reduction error grows like the rounding of
theta itself (|theta| * 1e-16), which no evaluation can undo. sin(r) and cos(r) are fdlibm's
minimax polynomials (Sun Microsystems 1993) evaluated in Estrin's form with fused multiply-adds,
and n mod 4 swaps and signs them: within two units in the last place of libm
(tests/test_core_trig.py). NaN and inf give NaN.

Why not math.sin and math.cos: the machine's Park angle is evaluated six times per tick of the
16 kHz loop (four RK4 stages, the current sensors, the controller), and libm's sincos call was a
third of the cost of a derivative evaluation: a call makes the compiler spill every live
floating-point register around it and cannot be scheduled with the rest. Written out here, in
IEEE double arithmetic whose fused multiply-adds are explicit (feed_twin.core.fma, rounded once
on every CPU; no fast-math), the result does not depend on the CPU either, where libm picks an
FMA or a non-FMA variant at run time.
"""

from __future__ import annotations

from numba import njit

from feed_twin.core.fma import fma

_TWO_OVER_PI = 0.63661977236758134308
_PIO2_HEAD = 1.57079632673412561417e00  # first 33 bits of pi/2
_PIO2_MID = 6.07710050630396597660e-11  # next 33 bits
_PIO2_TAIL = 2.02226624879595063154e-21  # pi/2 - head - mid

# sin(r) = r + r^3 (S1 + r^2 S2 + ... + r^10 S6) on |r| <= pi/4
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
# cos(r) = 1 - r^2/2 + r^4 (C1 + r^2 C2 + ... + r^10 C6) on |r| <= pi/4
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11


_ROUND = 6755399441055744.0  # 1.5 * 2^52: x + _ROUND - _ROUND rounds x to an integer


@njit(cache=True, inline="always", error_model="numpy")
def sincos(theta: float) -> tuple[float, float]:
    """(cos(theta), sin(theta)) within about one unit in the last place."""
    n = (theta * _TWO_OVER_PI + _ROUND) - _ROUND  # nearest integer (ties to even)
    r = ((theta - n * _PIO2_HEAD) - n * _PIO2_MID) - n * _PIO2_TAIL
    # the polynomials in Estrin's form: a tree of products instead of Horner's chain, which
    # halves the latency of this call on the loop's critical path
    z = r * r
    z2 = z * z
    z4 = z2 * z2
    ps = fma(z4, fma(z, _S6, _S5), fma(z2, fma(z, _S4, _S3), fma(z, _S2, _S1)))
    pc = fma(z4, fma(z, _C6, _C5), fma(z2, fma(z, _C4, _C3), fma(z, _C2, _C1)))
    s = fma(z * r, ps, r)
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + fma(z2, pc, (1.0 - w) - hz)
    q = int(n) & 3
    if q & 1:
        c, s = -s, c
    if q & 2:
        c, s = -c, -s
    return c, s


# cos(d) - 1 = z (-1/2 + z/24 - z^2/720 + ...) and sin(d) = d (1 - z/6 + ...), z = d^2: Taylor
# series to degree 12 and 13 in d; the first term left out is below 5e-20 for |d| <= NEAR
NEAR = 0.25  # [rad] largest increment sincos_near rotates by; beyond it, it calls sincos
_TC2, _TC4, _TC6, _TC8, _TC10, _TC12 = (
    -1 / 2,
    1 / 24,
    -1 / 720,
    1 / 40320,
    -1 / 3628800,
    1 / 479001600,
)
_TS3, _TS5, _TS7, _TS9 = -1 / 6, 1 / 120, -1 / 5040, 1 / 362880
_TS11, _TS13 = -1 / 39916800, 1 / 6227020800


@njit(error_model="numpy", forceinline=False)
def _sincos_far(theta: float) -> tuple[float, float]:
    """`sincos` out of line: sincos_near's rare fallback. Inlined there, every RK4 stage of the
    compiled loop carried a second copy of sincos, and the kernel took twice as long to compile."""
    return sincos(theta)


@njit(error_model="numpy", forceinline=True)
def sincos_near(theta: float, theta0: float, c0: float, s0: float) -> tuple[float, float]:
    """(cos(theta), sin(theta)) from (c0, s0) = sincos(theta0) of a nearby angle theta0.

    The pair is rotated by d = theta - theta0: cos(theta0 + d) = c0 + (c0 (cos d - 1) - s0 sin d),
    the small corrections written as the Taylor series above, so that d = 0 returns (c0, s0)
    exactly. A quarter of the operations of `sincos` and no range reduction: the compiled loop
    evaluates the Park angle of each RK4 stage this way from its value at the start of the
    tick, where the rotor has turned by at most h * omega_e (0.16 rad at 6000 rpm, 4 pole pairs,
    62.5 us). Within four units in the last place of libm (tests/test_core_trig.py); beyond
    |d| > NEAR, or with a NaN anywhere, it is `sincos(theta)`.
    """
    d = theta - theta0
    if not abs(d) <= NEAR:
        return _sincos_far(theta)
    z = d * d
    z2 = z * z
    z4 = z2 * z2
    # Estrin's form, as in sincos: a tree of products, half the latency of Horner's chain
    cm = z * fma(z4, fma(z, _TC12, _TC10), fma(z2, fma(z, _TC8, _TC6), fma(z, _TC4, _TC2)))
    sn = fma(
        d * z, fma(z4, fma(z, _TS13, _TS11), fma(z2, fma(z, _TS9, _TS7), fma(z, _TS5, _TS3))), d
    )
    return fma(c0, cm, fma(-s0, sn, c0)), fma(s0, cm, fma(c0, sn, s0))


@njit(cache=True, inline="always", error_model="numpy")
def sincos_anchored(
    theta: float, theta_a: float, c_a: float, s_a: float
) -> tuple[float, float, float, float, float]:
    """(cos(theta), sin(theta), and the anchor to keep): `sincos_near` from the anchor
    (theta_a, c_a, s_a) while theta stays within NEAR of it, else `sincos` and a new anchor.

    For an angle that moves a little from call to call (the drive's encoder angle, tick by
    tick): every pair is one rotation away from an exact evaluation, so rounding never
    accumulates however long a run lasts. A NaN angle gives NaN and a NaN anchor, which the
    next finite angle replaces.
    """
    if abs(theta - theta_a) <= NEAR:
        c, s = sincos_near(theta, theta_a, c_a, s_a)
        return c, s, theta_a, c_a, s_a
    c, s = sincos(theta)
    return c, s, theta, c, s
