"""Kinds and values of the Python -> C translation (feed_twin.native.translate).

A value is a C expression with a kind: `Scalar` (double, int64_t, uint64_t or int for a
bool), `TupleKind` (its parts are values), `ArrayKind` (a `double *`), or an object known at
translation time (a module, a function) that only calls and attributes may use. `PRELUDE` holds
the C helpers with numba's semantics that every generated file starts with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import SupportsFloat

import numpy as np


class TranslationError(ValueError):
    """A construct of a numba function that the C backend cannot translate."""


@dataclass(frozen=True)
class Scalar:
    ctype: str  # double, int64_t, uint64_t, int (bool)


@dataclass(frozen=True)
class TupleKind:
    items: tuple


@dataclass(frozen=True)
class ArrayKind:
    fixed: tuple = ()  # ((slot, value), ...): slots read as literals
    table: str = ""  # element type of a static const table, "" for a double * argument


DOUBLE, INT, UINT, BOOL = Scalar("double"), Scalar("int64_t"), Scalar("uint64_t"), Scalar("int")
_RANK = {"int": 0, "int64_t": 1, "uint64_t": 2, "double": 3}


@dataclass
class Val:
    code: str | None
    kind: object
    const: object = None  # the Python value when known at translation time
    parts: list = field(default_factory=list)  # of a tuple
    side_effect: bool = False

    @property
    def c(self) -> str:
        """The C expression (a tuple, a module or a function has none)."""
        if self.code is None:
            raise TranslationError(f"a {describe(self.kind)} has no C expression")
        return self.code

    @property
    def ctype(self) -> str:
        """The C type of a scalar value."""
        return scalar_ctype(self.kind)


def scalar_ctype(kind: object) -> str:
    if not isinstance(kind, Scalar):
        raise TranslationError(f"a {describe(kind)} where a scalar is needed")
    return kind.ctype


def var(name: str) -> str:
    return f"v_{name}"


def describe(kind) -> str:
    if isinstance(kind, Scalar):
        return {"int": "bool"}.get(kind.ctype, kind.ctype)
    if isinstance(kind, TupleKind):
        return f"tuple of {len(kind.items)}"
    if isinstance(kind, ArrayKind):
        return "array"
    return "Python object"


def flat_names(base: str, kind) -> list[tuple[str, str]]:
    if isinstance(kind, Scalar):
        return [(base, kind.ctype)]
    if isinstance(kind, TupleKind):
        return [n for i, k in enumerate(kind.items) for n in flat_names(f"{base}_{i}", k)]
    raise TranslationError(f"a {describe(kind)} has no scalar parts")


def items(v: Val) -> list[Val] | None:
    return v.parts if isinstance(v.kind, TupleKind) else None


def flatten(v: Val) -> list[Val]:
    if isinstance(v.kind, TupleKind):
        return [s for p in v.parts for s in flatten(p)]
    return [v]


def unify(a, b):
    if a == b:
        return a
    if isinstance(a, Scalar) and isinstance(b, Scalar):
        if {a.ctype, b.ctype} == {"int64_t", "uint64_t"}:
            return None
        return a if _RANK[a.ctype] >= _RANK[b.ctype] else b
    if isinstance(a, TupleKind) and isinstance(b, TupleKind) and len(a.items) == len(b.items):
        merged = tuple(unify(x, y) for x, y in zip(a.items, b.items, strict=True))
        return None if None in merged else TupleKind(merged)
    return None


def cast(v: Val, ctype: str) -> str:
    if v.kind == Scalar(ctype):
        return v.c
    if isinstance(v.const, SupportsFloat) and ctype == "double" and not isinstance(v.const, bool):
        return literal(float(v.const))
    return f"(({ctype})({v.code}))"


def literal(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, (int, np.integer)):
        return (
            f"INT64_C({int(value)})"
            if not isinstance(value, np.unsignedinteger)
            else (f"UINT64_C({int(value)})")
        )
    value = float(value)
    if math.isnan(value):
        return "NAN"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    return value.hex() if value >= 0 else f"(-{(-value).hex()})"


def constant(value) -> Val:
    if isinstance(value, (bool, np.bool_)):
        return Val(literal(value), BOOL, const=bool(value))
    if isinstance(value, np.unsignedinteger):
        return Val(literal(value), UINT, const=value)
    if isinstance(value, (int, np.integer)):
        return Val(literal(value), INT, const=int(value))
    if isinstance(value, (float, np.floating)):
        return Val(literal(value), DOUBLE, const=float(value))
    if isinstance(value, tuple):
        parts = [constant(v) for v in value]
        return Val(None, TupleKind(tuple(p.kind for p in parts)), const=value, parts=parts)
    return Val(None, None, const=value)  # a module, function, ... : calls and attributes only


# C helpers with numba's semantics, emitted once at the top of every generated file
PRELUDE = r"""
#define FT_INLINE static inline __attribute__((always_inline))
FT_INLINE double ft_max_d(double a, double v) { return v > a ? v : a; }
FT_INLINE double ft_min_d(double a, double v) { return v < a ? v : a; }
FT_INLINE int64_t ft_max_i(int64_t a, int64_t v) { return v > a ? v : a; }
FT_INLINE int64_t ft_min_i(int64_t a, int64_t v) { return v < a ? v : a; }
FT_INLINE int64_t ft_abs_i(int64_t a) { return a < 0 ? -a : a; }
/* A literal power-of-two divisor (the delay ring's length) is a mask: the same floor modulo in
   two's complement, one instruction instead of a division's sign fix-ups. */
FT_INLINE int64_t ft_mod_i(int64_t a, int64_t b)
{
    if (__builtin_constant_p(b) && b > 0 && (b & (b - 1)) == 0) return a & (b - 1);
    int64_t r = a % b;
    return (r != 0 && ((r < 0) != (b < 0))) ? r + b : r;
}
FT_INLINE int64_t ft_floordiv_i(int64_t a, int64_t b)
{ int64_t q = a / b; return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q; }
FT_INLINE double ft_mod_d(double a, double b)
{
    double r = fmod(a, b);
    if (r != 0.0) { if ((b < 0.0) != (r < 0.0)) r += b; } else { r = copysign(0.0, b); }
    return r;
}
"""
