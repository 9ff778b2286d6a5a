"""Structure of feed_twin/: short functions and layers without import cycles.

Read from the source with `ast`, nothing imported. An import counts wherever it stands: at
module level, inside a function or under `if TYPE_CHECKING:` (each one ties the two modules'
designs together, whether or not Python runs it at import time). `import a.b.c` and
`from a.b import c` (c a submodule) depend on a.b.c alone, not on the packages a and a.b: a
package's `__init__` that re-exports its own modules would otherwise form a cycle with each.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "feed_twin"
MAX_FUNCTION_LINES = 120


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of feed_twin (packages by their __init__)."""
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _functions(tree: ast.AST) -> Iterator[ast.FunctionDef | ast.AsyncFunctionDef]:
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield node


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imported(module: str, path: Path, modules: Mapping[str, Path]) -> set[str]:
    """The feed_twin modules that `module` imports anywhere in its source."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name in modules)
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(node, module, is_package)
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in modules:
                    found.add(sub)
                elif target in modules:
                    found.add(target)
    found.discard(module)
    return found


def _import_graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imported(name, path, modules) for name, path in modules.items()}


def _cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one member (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
            elif child not in index:
                index[child] = low[child] = counter
                counter += 1
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.get(child, ())))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return sorted(found)


def _describe(cycles: list[list[str]], graph: Mapping[str, set[str]]) -> str:
    lines = []
    for members in cycles:
        inside = set(members)
        edges = [f"{a} -> {b}" for a in members for b in sorted(graph[a]) if b in inside]
        lines.append(f"{', '.join(members)}: {'; '.join(edges)}")
    return "\n".join(lines)


def _subpackage(module: str) -> str:
    """feed_twin.plant.assembly -> feed_twin.plant; a top-level module stands for itself."""
    return ".".join(module.split(".")[:2])


def test_no_function_is_longer_than_the_limit():
    too_long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for func in _functions(tree):
            first = min([func.lineno, *(d.lineno for d in func.decorator_list)])
            length = (func.end_lineno or func.lineno) - first + 1
            if length > MAX_FUNCTION_LINES:
                where = path.relative_to(ROOT)
                too_long.append(f"{where}:{func.lineno}: {func.name} has {length} lines")
    assert not too_long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(too_long)


def test_no_import_cycle_between_modules():
    graph = _import_graph()
    cycles = _cycles(graph)
    assert not cycles, "import cycles between modules:\n" + _describe(cycles, graph)


def test_no_import_cycle_between_subpackages():
    graph: dict[str, set[str]] = {}
    for module, imported in _import_graph().items():
        edges = graph.setdefault(_subpackage(module), set())
        edges.update(_subpackage(m) for m in imported)
    for package, edges in graph.items():
        edges.discard(package)
    cycles = _cycles(graph)
    assert not cycles, "import cycles between subpackages:\n" + _describe(cycles, graph)


def test_the_cycle_finder_finds_a_cycle_and_only_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": set(), "f": {"f"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_relative_and_function_level_imports_are_edges(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("def f():\n    from .b import g\n    return g\n")
    (pkg / "b.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import pkg.a\n"
    )
    modules = {"pkg": pkg / "__init__.py", "pkg.a": pkg / "a.py", "pkg.b": pkg / "b.py"}
    graph = {name: _imported(name, path, modules) for name, path in modules.items()}
    assert graph == {"pkg": set(), "pkg.a": {"pkg.b"}, "pkg.b": {"pkg.a"}}
    assert _cycles(graph) == [["pkg.a", "pkg.b"]]


def test_codegen_reads_the_assembly_only_through_its_view():
    graph = _import_graph()
    assert "feed_twin.plant.codegen" in graph["feed_twin.plant.assembly"]
    assert "feed_twin.plant.assembly" not in graph["feed_twin.plant.codegen"]
    assert "feed_twin.plant.assembly" not in graph["feed_twin.plant.view"]
    assert graph["feed_twin.plant.view"] == set()
