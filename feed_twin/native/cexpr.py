"""Expressions of the Python -> C translation (feed_twin.native.translate): each Python
expression node becomes a C expression of a kind (feed_twin.native.ckinds), numba's semantics
kept (min/max on ties, int64 wrapping, `**` by an integer as numba multiplies, math.floor as an
int64).
"""

from __future__ import annotations

import ast
import builtins
import math
import operator

import numpy as np
from numba.core.registry import CPUDispatcher

from feed_twin.core import fma as _fma_module
from feed_twin.native.ckinds import (
    BOOL,
    DOUBLE,
    INT,
    UINT,
    ArrayKind,
    Scalar,
    TranslationError,
    TupleKind,
    Val,
    cast,
    constant,
    describe,
    flat_names,
    flatten,
    scalar_ctype,
    unify,
    var,
)

__all__ = ["Expressions", "TranslationError"]


_MATH = {
    math.sqrt: "sqrt",
    math.exp: "exp",
    math.log: "log",
    math.sin: "sin",
    math.cos: "cos",
    math.tan: "tan",
    math.atan2: "atan2",
    math.hypot: "hypot",
    math.erfc: "erfc",
    math.copysign: "copysign",
    math.fabs: "fabs",
    math.atan: "atan",
    math.tanh: "tanh",
}
_OPS = {
    ast.Add: "+",
    ast.Sub: "-",
    ast.Mult: "*",
    ast.BitAnd: "&",
    ast.BitOr: "|",
    ast.BitXor: "^",
    ast.LShift: "<<",
    ast.RShift: ">>",
}
_CMP = {ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==", ast.NotEq: "!="}
_FOLD = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
    ast.BitAnd: operator.and_,
    ast.BitOr: operator.or_,
    ast.LShift: operator.lshift,
    ast.RShift: operator.rshift,
}


class Expressions:
    """Expression translation for one function body (`b`: its translate._Body)."""

    def __init__(self, body) -> None:
        self.b = body

    def fail(self, node, what):
        return self.b.fail(node, what)

    def scalar(self, node: ast.expr, d: int) -> Val:
        v = self.value(node, d)
        if not isinstance(v.kind, Scalar):
            raise self.fail(node, f"expected a number, got a {describe(v.kind)}")
        return v

    def value(self, node: ast.expr, d: int) -> Val:
        method = getattr(self, f"_{type(node).__name__}", None)
        if method is None:
            raise self.fail(node, f"the expression {type(node).__name__} does not translate to C")
        return method(node, d)

    def _Constant(self, node, d):
        if node.value is None or isinstance(node.value, (str, bytes, complex)):
            raise self.fail(node, f"the constant {node.value!r} does not translate to C")
        return constant(node.value)

    def _Name(self, node, d):
        kinds = self.b.fn.kinds
        if node.id in kinds:
            kind = kinds[node.id]
            return self._local(var(node.id), kind)
        if node.id in self.b.globs:
            return self._global(self.b.globs[node.id], node.id, node)
        if hasattr(builtins, node.id):
            return Val(None, None, const=getattr(builtins, node.id))
        raise self.fail(node, f"the name {node.id} is not defined")

    def _local(self, code: str, kind) -> Val:
        if isinstance(kind, TupleKind):
            parts = [self._local(f"{code}_{i}", k) for i, k in enumerate(kind.items)]
            return Val(None, kind, parts=parts)
        return Val(code, kind)

    def _global(self, obj, name: str, node) -> Val:
        if isinstance(obj, np.ndarray):
            cname = self.b.tr.table(obj, name.strip("_"))
            return Val(cname, ArrayKind(table="double" if obj.dtype.kind == "f" else "int64_t"))
        return constant(obj)

    def _Attribute(self, node, d):
        base = self.value(node.value, d)
        if base.kind is not None or base.const is None:
            raise self.fail(node, f"attribute .{node.attr} of a runtime value does not translate")
        return self._global(getattr(base.const, node.attr), node.attr, node)

    def _Tuple(self, node, d):
        parts = [self.value(e, d) for e in node.elts]
        for p in parts:
            if p.kind is None or isinstance(p.kind, ArrayKind):
                raise self.fail(node, "a tuple holds numbers and tuples only")
        return Val(None, TupleKind(tuple(p.kind for p in parts)), parts=parts)

    def _Subscript(self, node, d):
        base = self.value(node.value, d)
        if isinstance(node.slice, ast.Slice):
            raise self.fail(node, "slices do not translate to C")
        if isinstance(base.kind, TupleKind):
            index = self.scalar(node.slice, d)
            if not isinstance(index.const, int):
                raise self.fail(node, "a tuple is indexed by a constant only")
            return base.parts[index.const]
        if not isinstance(base.kind, ArrayKind):
            raise self.fail(node, f"cannot index a {describe(base.kind)}")
        index = self.scalar(node.slice, d)
        if index.ctype == "double":
            raise self.fail(node, "an array index must be an integer")
        fixed = dict(base.kind.fixed)
        if isinstance(index.const, int) and index.const in fixed:
            return constant(float(fixed[index.const]))
        kind = Scalar(base.kind.table) if base.kind.table else DOUBLE
        return Val(f"{base.code}[{index.code}]", kind)

    def element_target(self, node: ast.Subscript, d: int) -> tuple[str, str]:
        base = self.value(node.value, d)
        if not isinstance(base.kind, ArrayKind) or base.kind.table:
            raise self.fail(node, "only an array argument's elements can be assigned")
        index = self.scalar(node.slice, d)
        if isinstance(index.const, int) and index.const in dict(base.kind.fixed):
            raise self.fail(node, f"slot {index.const} is fixed at translation and cannot be set")
        return base.c, index.c

    def _UnaryOp(self, node, d):
        v = self.scalar(node.operand, d)
        if isinstance(node.op, ast.Not):
            return Val(f"(!{v.code})", BOOL)
        if isinstance(node.op, ast.USub):
            kind = INT if v.kind == BOOL else v.kind
            const = -v.const if isinstance(v.const, (int, float)) else None
            if const is not None and not isinstance(const, bool):
                return constant(const)
            return Val(f"(-{v.code})", kind)
        if isinstance(node.op, ast.UAdd):
            return v
        return Val(f"(~{v.code})", v.kind)

    def _BoolOp(self, node, d):
        vals = [self.scalar(v, d) for v in node.values]
        for v, n in zip(vals, node.values, strict=True):
            if v.kind != BOOL:
                raise self.fail(n, "and/or of non-boolean values does not translate to C")
        op = " && " if isinstance(node.op, ast.And) else " || "
        return Val("(" + op.join(v.c for v in vals) + ")", BOOL)

    def _Compare(self, node, d):
        left = self.scalar(node.left, d)
        terms = []
        for op, right_node in zip(node.ops, node.comparators, strict=True):
            if type(op) not in _CMP:
                raise self.fail(node, f"the comparison {type(op).__name__} does not translate")
            right = self.scalar(right_node, d)
            if {left.ctype, right.ctype} == {"int64_t", "uint64_t"}:
                raise self.fail(node, "comparison of int64 with uint64")
            terms.append(f"({left.code} {_CMP[type(op)]} {right.code})")
            left = right
        return Val("(" + " && ".join(terms) + ")", BOOL)

    def _IfExp(self, node, d):
        cond = self.scalar(node.test, d)
        a, b = self.value(node.body, d), self.value(node.orelse, d)
        kind = unify(a.kind, b.kind)
        if kind is None or isinstance(kind, ArrayKind):
            raise self.fail(node, f"branches give a {describe(a.kind)} and a {describe(b.kind)}")
        if isinstance(kind, Scalar):
            return Val(f"({cond.code} ? {cast(a, kind.ctype)} : {cast(b, kind.ctype)})", kind)
        c = self.b.to_temp(cond, d)
        fa, fb = flatten(a), flatten(b)
        types = [t for _, t in flat_names("x", kind)]
        flat = [
            Val(f"({c.code} ? {cast(x, t)} : {cast(y, t)})", Scalar(t))
            for x, y, t in zip(fa, fb, types, strict=True)
        ]
        return _rebuild(kind, iter(flat))

    def _BinOp(self, node, d):
        return self.binop(node.op, self.value(node.left, d), self.value(node.right, d), node)

    def binop(self, op, a: Val, b: Val, node) -> Val:
        if not (isinstance(a.kind, Scalar) and isinstance(b.kind, Scalar)):
            raise self.fail(
                node, f"{type(op).__name__} of a {describe(a.kind)} and a {describe(b.kind)}"
            )
        if type(a.const) is int and type(b.const) is int and type(op) in _FOLD:
            return constant(_FOLD[type(op)](a.const, b.const))
        ta, tb = a.kind.ctype, b.kind.ctype
        if {ta, tb} == {"int64_t", "uint64_t"}:
            raise self.fail(node, "arithmetic mixing int64 and uint64 (numba gives a float64)")
        if isinstance(op, ast.Div):
            return Val(f"({cast(a, 'double')} / {cast(b, 'double')})", DOUBLE)
        if isinstance(op, ast.Pow):
            return self._power(a, b, node)
        kind = unify(a.kind, b.kind)
        if kind == BOOL:
            kind = INT
        ct = scalar_ctype(kind)
        if isinstance(op, (ast.Mod, ast.FloorDiv)):
            if ct == "double":
                if isinstance(op, ast.FloorDiv):
                    raise self.fail(node, "// of floats does not translate to C")
                return Val(f"ft_mod_d({cast(a, ct)}, {cast(b, ct)})", DOUBLE)
            if ct == "uint64_t":
                sym = "%" if isinstance(op, ast.Mod) else "/"
                return Val(f"({a.code} {sym} {b.code})", kind)
            fn = "ft_mod_i" if isinstance(op, ast.Mod) else "ft_floordiv_i"
            return Val(f"{fn}({cast(a, ct)}, {cast(b, ct)})", kind)
        if type(op) not in _OPS:
            raise self.fail(node, f"the operator {type(op).__name__} does not translate to C")
        sym = _OPS[type(op)]
        if sym in "&|^<<>>" and ct == "double":
            raise self.fail(node, f"bit operation {sym} on a float")
        return Val(f"({cast(a, ct)} {sym} {cast(b, ct)})", kind)

    def _power(self, a: Val, b: Val, node) -> Val:
        if not (type(b.const) is int and 0 <= b.const <= 16):
            raise self.fail(node, "** needs a constant integer exponent 0..16")
        # numba's power by a literal integer: square-and-multiply from the lowest bit
        base, n = self.b.to_temp(a, 0) if a.const is None and not _is_name(a) else a, b.const
        result: str | None = None
        while n:
            if n & 1:
                result = base.code if result is None else f"({result} * {base.code})"
            n >>= 1
            if n:
                base = Val(f"({base.code} * {base.code})", base.kind)
        return Val(result or cast(constant(1), a.ctype), a.kind)

    def _Call(self, node, d):
        if node.keywords:
            raise self.fail(node, "keyword arguments do not translate to C")
        func = self.value(node.func, d)
        if func.kind is not None:
            raise self.fail(node, "only functions known at translation time can be called")
        obj = func.const
        args = [self.value(a, d) for a in node.args]
        if obj is _fma_module.fma:
            return Val(
                f"fma({', '.join(cast(self._num(a, node), 'double') for a in args)})", DOUBLE
            )
        if obj in (min, max):
            return self._minmax(obj, args, node)
        if obj is abs:
            v = self._num(args[0], node)
            return Val(
                f"fabs({v.code})" if v.kind == DOUBLE else f"ft_abs_i({cast(v, 'int64_t')})",
                DOUBLE if v.kind == DOUBLE else INT,
            )
        casts = {
            int: INT,
            float: DOUBLE,
            bool: BOOL,
            np.uint64: UINT,
            np.int64: INT,
            np.float64: DOUBLE,
        }
        if obj in casts and len(args) == 1:
            v = self._num(args[0], node)
            if obj is bool:
                return Val(f"({v.code} != 0)", BOOL)
            return Val(cast(v, casts[obj].ctype), casts[obj])
        if obj in (math.floor, math.ceil):  # numba: an int64, as Python's
            fn = "floor" if obj is math.floor else "ceil"
            return Val(f"((int64_t){fn}({cast(self._num(args[0], node), 'double')}))", INT)
        if obj is math.isfinite:
            return Val(f"(isfinite({cast(self._num(args[0], node), 'double')}) != 0)", BOOL)
        if obj in _MATH:
            vals = ", ".join(cast(self._num(a, node), "double") for a in args)
            return Val(f"{_MATH[obj]}({vals})", DOUBLE)
        if isinstance(obj, CPUDispatcher) or callable(obj) and hasattr(obj, "__code__"):
            return self._user_call(obj, args, node, d)
        raise self.fail(
            node, f"the call of {getattr(obj, '__name__', obj)!r} does not translate to C"
        )

    def _num(self, v: Val, node) -> Val:
        if not isinstance(v.kind, Scalar):
            raise self.fail(node, f"expected a number, got a {describe(v.kind)}")
        return v

    def _minmax(self, fn, args, node) -> Val:
        if len(args) < 2:
            raise self.fail(
                node, f"{fn.__name__}() of one argument (a sequence) does not translate"
            )
        acc = self._num(args[0], node)
        for v in args[1:]:
            kind = unify(acc.kind, self._num(v, node).kind)
            suffix = "d" if kind == DOUBLE else "i"
            ct = "double" if kind == DOUBLE else "int64_t"
            acc = Val(f"ft_{fn.__name__}_{suffix}({cast(acc, ct)}, {cast(v, ct)})", Scalar(ct))
        return acc

    def _user_call(self, obj, args: list[Val], node, d) -> Val:
        for a in args:
            if a.kind is None:
                raise self.fail(node, "a function or module passed as an argument")
        cname, ret = self.b.tr.function(obj, tuple(a.kind for a in args))
        cargs = []
        for a in args:
            cargs += [a.code] if isinstance(a.kind, ArrayKind) else [s.code for s in flatten(a)]
        if isinstance(ret, TupleKind):
            temps = []
            for _, t in flat_names("r", ret):
                name = self.b.tr.temp()
                self.b.emit(f"{t} {name};", d)
                temps.append(Val(name, Scalar(t)))
            cargs += [f"&{t.code}" for t in temps]
            self.b.emit(f"{cname}({', '.join(cargs)});", d)
            return _rebuild(ret, iter(temps))
        call = f"{cname}({', '.join(cargs)})"
        if ret is None:
            self.b.emit(f"{call};", d)
            return Val("", None, const=None)
        return Val(call, ret, side_effect=True)


def _is_name(v: Val) -> bool:
    return v.code is not None and v.code.replace("_", "").isalnum()


def _rebuild(kind, flat) -> Val:
    if isinstance(kind, TupleKind):
        parts = [_rebuild(k, flat) for k in kind.items]
        return Val(None, kind, parts=parts)
    return next(flat)
