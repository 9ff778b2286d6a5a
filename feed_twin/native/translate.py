"""Translation of the numba-compiled laws into C: one source of physics for two backends.

The component laws, the generated plant functions and the controller's tick are restricted
Python that numba compiles: scalars, tuples of scalars, 1-D float64 arrays, `if`/`while`/`for
... in range(...)`, calls of other such functions and of `math`. `Translator` reads a
function's source with `ast` and writes a C function per argument signature, as numba
specialises per argument types:
- float64, int64, uint64 and bool are `double`, `int64_t`, `uint64_t` and `int`; the C
  arithmetic follows numba's (int / int is a double; int64 wraps, so the C build uses -fwrapv;
  min/max keep the first argument on ties; `%` and `//` round toward minus infinity);
- a tuple is its flattened scalars: tuple arguments are several C arguments, a tuple result is
  written through pointers, so `a, b = f(x)` needs no struct and the C compiler keeps the values
  in registers once it inlines (every function is `static inline` always_inline, like
  numba's forceinline);
- a 1-D array argument is a `double *`; an array may carry slots fixed at translation time
  (`ArrayKind.fixed`), read as literals, as the engine compiles the controller's structure
  into its kernel;
- module globals are read once: numbers become exact literals (hexadecimal floats), numpy
  arrays `static const` tables, tuples of numbers constant tuples.
Anything else (lists, strings, dicts, comprehensions, exceptions, keyword arguments, 2-D
indexing, ...) raises `TranslationError` naming the function, the file and line and the construct.
"""

from __future__ import annotations

import ast
import inspect
import re
import textwrap
from dataclasses import dataclass, field

import numpy as np
from numba.core.registry import CPUDispatcher

from feed_twin.native import ckinds as cx
from feed_twin.native.cexpr import Expressions
from feed_twin.native.ckinds import ArrayKind, Scalar, TranslationError, TupleKind, Val

__all__ = ["ArrayKind", "Scalar", "TranslationError", "Translator", "TupleKind"]


@dataclass
class _Function:
    """What is known of one specialisation while its body is translated."""

    name: str
    where: str  # "module.function (file:line)" for messages
    kinds: dict[str, object] = field(default_factory=dict)  # local name -> kind
    params: set[str] = field(default_factory=set)
    ret: object = None  # kind of the returned value (None: nothing returned yet)


class Translator:
    """Collects C functions and tables for Python functions, specialised per argument kinds."""

    def __init__(self, prefix: str = "ft") -> None:
        self.prefix = prefix
        self.functions: list[str] = []  # C definitions, callees before callers
        self.tables: list[str] = []
        self._specs: dict[tuple, tuple[str, object]] = {}  # key -> (C name, return kind)
        self._table_names: dict[int, str] = {}
        self._names: set[str] = set()
        self._active: set[tuple] = set()  # specialisations being translated
        self._tmp = 0

    def function(self, func, kinds: tuple) -> tuple[str, object]:
        """The C name and return kind of `func` specialised for argument `kinds`."""
        py = func.py_func if isinstance(func, CPUDispatcher) else func
        key = (py, tuple(kinds))
        if key in self._specs:
            return self._specs[key]
        tree, where, line0 = _parse(py)
        if key in self._active:
            raise TranslationError(f"{where}: a recursive call does not translate to C")
        self._active.add(key)
        args = tree.args
        if args.vararg or args.kwarg or args.kwonlyargs or args.defaults:
            raise TranslationError(f"{where}: only plain positional parameters translate to C")
        names = [a.arg for a in args.args]
        if len(names) != len(kinds):
            raise TranslationError(
                f"{where}: called with {len(kinds)} arguments, takes {len(names)}"
            )
        base = f"{self.prefix}_{py.__module__.rsplit('.', 1)[-1]}_{py.__name__}".replace("__", "_")
        cname, i = base, 1
        while cname in self._names:
            i += 1
            cname = f"{base}_{i}"
        self._names.add(cname)
        known: dict[str, object] = dict(zip(names, kinds, strict=True))
        ret, body, fn = None, "", None
        for _ in range(6):  # until the locals' types and the return kind stop widening
            fn = _Function(name=cname, where=where, params=set(names), kinds=dict(known), ret=ret)
            body = _Body(self, fn, py.__globals__, line0).block(tree.body, 1)
            if fn.kinds == known and fn.ret == ret:
                break
            known, ret = dict(fn.kinds), fn.ret
        else:  # pragma: no cover - widening settles within a few passes
            raise TranslationError(f"{where}: the types of the locals do not settle")
        final = fn
        self._active.discard(key)
        self._specs[key] = (cname, final.ret)
        self.functions.append(_definition(final, names, kinds, body))
        return cname, final.ret

    def table(self, array: np.ndarray, name: str) -> str:
        """A module-level numpy array as a static const C table; its C name."""
        if id(array) in self._table_names:
            return self._table_names[id(array)]
        a = np.asarray(array)
        if a.ndim != 1 or a.dtype.kind not in "fiu":
            raise TranslationError(f"global {name}: only 1-D numeric arrays translate to C")
        cname = f"{self.prefix}_tab_{name}_{len(self._table_names)}"
        ctype = "double" if a.dtype.kind == "f" else "int64_t"
        values = ", ".join(cx.literal(float(v) if a.dtype.kind == "f" else int(v)) for v in a)
        self.tables.append(f"static const {ctype} {cname}[{a.size}] = {{{values}}};")
        self._table_names[id(array)] = cname
        return cname

    def temp(self) -> str:
        self._tmp += 1
        return f"t{self._tmp}"

    def source(self) -> str:
        return "\n".join(self.tables + [""] + self.functions)


class Source:
    """A function given as source text (the emitter's own glue), with the globals it reads."""

    __module__ = "feed_twin.native.generated"

    def __init__(self, text: str, name: str, globs: dict) -> None:
        self.text, self.__name__, self.__globals__ = text, name, globs


def _parse(py) -> tuple[ast.FunctionDef, str, int]:
    if isinstance(py, Source):
        node = ast.parse(py.text).body[0]
        assert isinstance(node, ast.FunctionDef)
        return node, f"feed_twin.native.generated.{py.__name__} (<generated>:2)", 1
    try:
        lines, line0 = inspect.getsourcelines(py)
        file = inspect.getsourcefile(py) or "<unknown>"
    except (OSError, TypeError) as exc:
        raise TranslationError(
            f"{py.__module__}.{py.__name__}: no source to translate ({exc})"
        ) from None
    tree = ast.parse(textwrap.dedent("".join(lines)))
    node = tree.body[0]
    where = f"{py.__module__}.{py.__name__} ({file}:{line0})"
    if not isinstance(node, ast.FunctionDef):
        raise TranslationError(f"{where}: not a function definition")
    return node, where, line0


def _definition(fn: _Function, names: list[str], kinds: tuple, body: str) -> str:
    params: list[str] = []
    for name, kind in zip(names, kinds, strict=True):
        if isinstance(kind, ArrayKind):
            params.append(f"double *restrict {cx.var(name)}")
        else:
            params += [f"{t} {v}" for v, t in cx.flat_names(cx.var(name), kind)]
    ret = fn.ret
    if isinstance(ret, TupleKind):
        params += [f"{t} *r{i}" for i, (_, t) in enumerate(cx.flat_names("r", ret))]
        rtype = "void"
    elif isinstance(ret, Scalar):
        rtype = ret.ctype
    elif isinstance(ret, ArrayKind):
        rtype = "double *"
    else:
        rtype = "void"
    decls = []
    for name, kind in fn.kinds.items():
        if name in fn.params:
            continue
        if isinstance(kind, ArrayKind):
            decls.append(f"    double *{cx.var(name)};")
        else:
            decls += [f"    {t} {v} = 0;" for v, t in cx.flat_names(cx.var(name), kind)]
    # a law's signature is shared by all its callers and tuple unpacking binds every slot, so a
    # parameter or local may go unread: said per name, as C does, instead of silencing -Wextra
    scalars = [p for p in params if "*" not in p] + [d for d in decls if "*" not in d]
    unread = [d.split("=")[0].split()[-1].rstrip(";") for d in scalars]
    unread = [name for name in unread if not _is_read(name, body)]
    arrays = [p.rsplit(" ", 1)[-1].lstrip("*") for p in params + decls if "*" in p]
    unread += [name for name in arrays if not re.search(rf"\b{name}\b", body)]
    decls += [f"    (void){name};" for name in unread]
    head = f"FT_INLINE {rtype}\n{fn.name}({', '.join(params) or 'void'})"
    return f"/* {fn.where} */\n{head}\n{{\n" + "\n".join(decls) + "\n" + body + "}\n"


def _is_read(name: str, body: str) -> bool:
    """Whether the C `body` reads `name` anywhere (not only stores into it)."""
    return re.search(rf"\b{re.escape(name)}\b(?!\s*=[^=])", body) is not None


class _Body:
    """Statements of one function body (expressions: feed_twin.native.cexpr)."""

    def __init__(self, tr: Translator, fn: _Function, globs: dict, line0: int) -> None:
        self.tr, self.fn, self.globs, self.line0 = tr, fn, globs, line0
        self.out: list[str] = []
        self.expr = Expressions(self)

    def fail(self, node: ast.AST, what: str) -> TranslationError:
        line = self.line0 + getattr(node, "lineno", 1) - 1
        file = self.fn.where.rsplit("(", 1)[-1].split(":")[0]
        return TranslationError(f"{self.fn.where.split(' (')[0]} ({file}:{line}): {what}")

    def emit(self, code: str, depth: int) -> None:
        self.out.append("    " * depth + code)

    def block(self, stmts: list[ast.stmt], depth: int) -> str:
        saved, self.out = self.out, []
        for s in stmts:
            self.stmt(s, depth)
        text = "".join(line + "\n" for line in self.out)
        self.out = saved
        return text

    def stmt(self, s: ast.stmt, d: int) -> None:
        if isinstance(s, ast.Expr):
            if isinstance(s.value, ast.Constant) and isinstance(s.value.value, str):
                return  # docstring
            v = self.expr.value(s.value, d)
            if isinstance(v, Val) and v.code and v.kind is not None and v.side_effect:
                self.emit(f"{v.code};", d)
        elif isinstance(s, ast.Assign):
            value = self.expr.value(s.value, d)
            for target in s.targets:
                self.assign(target, value, d)
        elif isinstance(s, ast.AugAssign):
            load = _as_load(s.target)
            value = self.expr.binop(s.op, self.expr.value(load, d), self.expr.value(s.value, d), s)
            self.assign(s.target, value, d)
        elif isinstance(s, ast.If):
            cond = self.expr.scalar(s.test, d)
            self.emit(f"if ({cond.code}) {{", d)
            self.out.append(self.block(s.body, d + 1).rstrip("\n"))
            if s.orelse:
                self.emit("} else {", d)
                self.out.append(self.block(s.orelse, d + 1).rstrip("\n"))
            self.emit("}", d)
        elif isinstance(s, ast.While):
            if s.orelse:
                raise self.fail(s, "while ... else does not translate to C")
            self.emit("for (;;) {", d)
            cond = self.expr.scalar(s.test, d + 1)
            self.emit(f"if (!({cond.code})) break;", d + 1)
            self.out.append(self.block(s.body, d + 1).rstrip("\n"))
            self.emit("}", d)
        elif isinstance(s, ast.For):
            self.for_loop(s, d)
        elif isinstance(s, ast.Return):
            self.ret(s, d)
        elif isinstance(s, ast.Pass):
            pass
        elif isinstance(s, ast.Break):
            self.emit("break;", d)
        elif isinstance(s, ast.Continue):
            self.emit("continue;", d)
        else:
            raise self.fail(s, f"the statement {type(s).__name__} does not translate to C")

    def declare(self, name: str, kind, node: ast.AST) -> None:
        old = self.fn.kinds.get(name)
        if old is None:
            self.fn.kinds[name] = kind
            return
        merged = cx.unify(old, kind)
        if merged is None:
            raise self.fail(
                node, f"{name} is bound to a {cx.describe(old)} and a {cx.describe(kind)}"
            )
        if merged != old and name in self.fn.params:
            raise self.fail(
                node, f"the parameter {name} would change type to {cx.describe(merged)}"
            )
        self.fn.kinds[name] = merged

    def assign(self, target: ast.expr, value: Val, d: int) -> None:
        if isinstance(target, ast.Name):
            self.declare(target.id, value.kind, target)
            kind = self.fn.kinds[target.id]
            if isinstance(kind, ArrayKind):
                self.emit(f"{cx.var(target.id)} = {value.code};", d)
                return
            pairs = list(
                zip(cx.flat_names(cx.var(target.id), kind), cx.flatten(value), strict=True)
            )
            if len(pairs) > 1:  # through temporaries: `c, s = -s, c` reads before it writes
                pairs = self.through_temps(pairs, d)
            for (name, ctype), v in pairs:
                self.emit(f"{name} = {cx.cast(v, ctype)};", d)
        elif isinstance(target, ast.Subscript):
            array, index = self.expr.element_target(target, d)
            if not isinstance(value.kind, Scalar):
                raise self.fail(target, "only a scalar can be stored into an array element")
            self.emit(f"{array}[{index}] = {cx.cast(value, 'double')};", d)
        elif isinstance(target, ast.Tuple):
            items = cx.items(value)
            if items is None or len(items) != len(target.elts):
                raise self.fail(
                    target,
                    f"cannot unpack a {cx.describe(value.kind)} into {len(target.elts)} names",
                )
            if len(items) > 1:
                items = [self.to_temp(v, d) for v in items]
            for t, v in zip(target.elts, items, strict=True):
                self.assign(t, v, d)
        else:
            raise self.fail(
                target, f"assignment to {type(target).__name__} does not translate to C"
            )

    def through_temps(self, pairs, d):
        out = []
        for (name, ctype), v in pairs:
            t = self.tr.temp()
            self.emit(f"const {ctype} {t} = {cx.cast(v, ctype)};", d)
            out.append(((name, ctype), Val(t, Scalar(ctype))))
        return out

    def to_temp(self, v: Val, d: int) -> Val:
        """A value stored into temporaries (constants and plain names stay as they are)."""
        if isinstance(v.kind, ArrayKind) or v.const is not None:
            return v
        if isinstance(v.kind, TupleKind):
            return Val(None, v.kind, parts=[self.to_temp(p, d) for p in cx.items(v)])
        t = self.tr.temp()
        self.emit(f"const {v.kind.ctype} {t} = {v.code};", d)
        return Val(t, v.kind)

    def for_loop(self, s: ast.For, d: int) -> None:
        if s.orelse:
            raise self.fail(s, "for ... else does not translate to C")
        it = s.iter
        if isinstance(it, ast.Call) and isinstance(it.func, ast.Name) and it.func.id == "range":
            if not isinstance(s.target, ast.Name):
                raise self.fail(s, "a range loop needs one loop variable")
            args = [self.expr.scalar(a, d) for a in it.args]
            if not 1 <= len(args) <= 3 or any(a.ctype == "double" for a in args):
                raise self.fail(s, "range() takes 1 to 3 integer arguments")
            start, stop = ("0", args[0]) if len(args) == 1 else (args[0].code, args[1])
            step = args[2] if len(args) == 3 else Val("1", Scalar("int64_t"), const=1)
            if not isinstance(step.const, int | np.integer) or step.const == 0:
                raise self.fail(s, "range() needs a constant, non-zero step")
            name = cx.var(s.target.id)
            self.declare(s.target.id, Scalar("int64_t"), s)
            stop_t = self.tr.temp()
            self.emit(f"const int64_t {stop_t} = {stop.code};", d)
            cmp = "<" if step.const > 0 else ">"
            self.emit(f"for ({name} = {start}; {name} {cmp} {stop_t}; {name} += {step.code}) {{", d)
            self.out.append(self.block(s.body, d + 1).rstrip("\n"))
            self.emit("}", d)
            return
        seq = self.expr.value(it, d)
        items = cx.items(seq)
        if items is None:
            raise self.fail(s, "a for loop runs over range(...) or a tuple only")
        self.emit("do {", d)  # `break` leaves the unrolled tuple loop
        for v in items:
            self.emit("{", d + 1)
            self.assign(s.target, v, d + 2)
            self.out.append(self.block(s.body, d + 2).rstrip("\n"))
            self.emit("}", d + 1)
        self.emit("} while (0);", d)

    def ret(self, s: ast.Return, d: int) -> None:
        if s.value is None or (isinstance(s.value, ast.Constant) and s.value.value is None):
            self.emit("return;", d)
            return
        value = self.expr.value(s.value, d)
        if isinstance(value.kind, ArrayKind):
            if value.kind.table:
                raise self.fail(s, "returning a table does not translate to C")
            self.fn.ret = value.kind
            self.emit(f"return {value.code};", d)
            return
        merged = value.kind if self.fn.ret is None else cx.unify(self.fn.ret, value.kind)
        if merged is None:
            raise self.fail(
                s, f"returns a {cx.describe(self.fn.ret)} and a {cx.describe(value.kind)}"
            )
        self.fn.ret = merged
        if isinstance(merged, TupleKind):
            flat = cx.flatten(value)
            types_ = [t for _, t in cx.flat_names("r", merged)]
            if len(flat) == len(types_):
                for i, (v, t) in enumerate(zip(flat, types_, strict=True)):
                    self.emit(f"*r{i} = {cx.cast(v, t)};", d)
            self.emit("return;", d)
        else:
            self.emit(f"return {cx.cast(value, cx.scalar_ctype(merged))};", d)


def _as_load(target: ast.expr) -> ast.expr:
    node = ast.fix_missing_locations(ast.parse(ast.unparse(target), mode="eval").body)
    ast.copy_location(node, target)
    return node
