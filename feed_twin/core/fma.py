# pyright: basic
# (numba's extension API, `intrinsic` and `overload`, hands untyped typing contexts and IR
# builders to these hooks: strict typing cannot follow it)
"""Fused multiply-add for the compiled hot loop: fma(a, b, c) = a*b + c, rounded once.

In numba-compiled code `fma` is LLVM's `llvm.fma.f64`: one instruction on a CPU with FMA, and a
call to the C library's `fma` (correctly rounded, as IEEE 754 requires) on one without. Either
way the result is the exactly rounded a*b + c, so it does not depend on the CPU; this is what
fast-math's `contract` could not promise, where the compiler fuses or not as the target allows.

The RK4 stage updates and the polynomials of the hot loop (sincos, exp_neg, smooth_sign) use it:
one operation instead of two (docs/performance.md).

Called from Python (the reference integration runs the laws' un-jitted `py_func`) it is the
plain a*b + c, rounded twice: the two paths then differ in the last bit of such a step, far
below the tolerance they are compared at (tests/test_sim_reference.py).
"""

from __future__ import annotations

from numba.core import types
from numba.extending import intrinsic, overload


def fma(a: float, b: float, c: float) -> float:
    """a*b + c (rounded once when compiled; see the module docstring)."""
    return a * b + c


@intrinsic
def _llvm_fma(typingctx, a, b, c):
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@overload(fma, inline="always")
def _fma_compiled(a, b, c):
    if not all(isinstance(t, (types.Float, types.Integer)) for t in (a, b, c)):
        return None

    def impl(a, b, c):
        return _llvm_fma(float(a), float(b), float(c))  # pyright: ignore[reportCallIssue]  (numba passes typingctx)

    return impl
