"""The layer order of feed_twin's subpackages is a contract: a layer uses only layers below it.

Read from the source with `ast`, nothing imported. An import counts wherever it stands (module
level, inside a function, under TYPE_CHECKING), and so does a string that names a feed_twin
module (`"feed_twin.ros.twin_node"`, `"feed_twin.cli:main"`): a module started by name is used as
surely as an imported one, but the import-cycle test (tests/test_structure.py) cannot see it.

The one declared exception is the node-role registry (feed_twin/nodeset/roles.py): it names the
ROS node modules that implement each role, as cli.SUBCOMMANDS names the subcommands' modules, so
that the guard, the recorder and the launcher below the ROS layer read one table. Those names
must be modules of feed_twin.ros, and they are checked to exist.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "feed_twin"

# Bottom to top. A subpackage (or top-level module) may use those of lower layers only; the
# members of one layer do not use each other.
LAYERS: tuple[frozenset[str], ...] = (
    frozenset({"core"}),  # signals, validation, the typed config loader
    frozenset({"plant", "control", "gcode", "io"}),  # physics, loops, G-code, file formats
    # the engines that run plant + control on a program; the independent truth machine (its own
    # equations, only the G-code planner below it)
    frozenset({"sim", "truth"}),
    frozenset({"nodeset"}),  # the node set as plain Python (config, wire, controller core)
    # identification (its reduced model for slow records derives its loops as the controller
    # node does, nodeset.controller_core)
    frozenset({"analysis"}),
    frozenset({"shadow"}),  # the shadow twin beside a measured axis
    frozenset({"machine"}),  # several axes
    frozenset({"linuxcnc"}),  # LinuxCNC configs and runs
    frozenset({"native"}),  # compiled backends (HAL component, FMU)
    frozenset({"launch"}),  # the run plan: processes and their nodes, plain data
    frozenset({"ros"}),  # the thin ROS 2 shells and the runners
    frozenset({"info_cli"}),  # `feed-twin info`
    frozenset({"cli", "__init__"}),  # the command line
)
# file -> the layer its module-name strings may reach although it sits lower, with the reason
DECLARED_UPWARD_NAMES = {
    "feed_twin/nodeset/roles.py": "ros",  # the role registry names each role's node module
}
# modules written at run time, not in the source tree
GENERATED_MODULES = {"feed_twin.native.generated"}  # native/translate.py: Source.__module__
MODULE_NAME = re.compile(r"feed_twin(?:\.\w+)+(?::\w+)?")


def _layer_of(package: str) -> int:
    for index, members in enumerate(LAYERS):
        if package in members:
            return index
    raise AssertionError(f"feed_twin.{package} is in no layer: add it to LAYERS")


def _package(path: Path) -> str:
    parts = path.relative_to(PACKAGE).parts
    return parts[0].removesuffix(".py")  # a subpackage's directory or a module's file


def _uses(path: Path) -> list[tuple[int, str, bool]]:
    """(line, used feed_twin module, named by a string) for every import and module-name string."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module, False))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name, False) for alias in node.names)
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and MODULE_NAME.fullmatch(node.value)
        ):
            found.append((node.lineno, node.value.split(":")[0], True))
    return sorted(use for use in found if use[1].startswith("feed_twin."))


def _module_file(module: str) -> Path | None:
    base = PACKAGE.joinpath(*module.split(".")[1:])
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _top_level_names(path: Path) -> set[str]:
    names = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(t.id for t in targets if isinstance(t, ast.Name))
    return names


def _exists(module: str) -> bool:
    """A feed_twin module or package of that dotted name, or a top-level name defined in one."""
    if module in GENERATED_MODULES or _module_file(module) is not None:
        return True
    parent, _, name = module.rpartition(".")
    path = _module_file(parent)
    return path is not None and name in _top_level_names(path)


def test_every_subpackage_is_in_a_layer():
    packages = {_package(p) for p in PACKAGE.rglob("*.py")}
    for package in sorted(packages):
        _layer_of(package)


def test_each_layer_uses_only_layers_below_it():
    wrong = []
    for path in sorted(PACKAGE.rglob("*.py")):
        package = _package(path)
        where = path.relative_to(ROOT).as_posix()
        for line, module, by_string in _uses(path):
            used = module.split(".")[1]
            if used == package:
                continue
            if by_string and DECLARED_UPWARD_NAMES.get(where) == used:
                continue
            if _layer_of(used) >= _layer_of(package):
                how = "names the module" if by_string else "imports"
                wrong.append(f"{where}:{line}: feed_twin.{package} {how} {module}")
    assert not wrong, "uses of a layer that is not below:\n" + "\n".join(wrong)


def test_module_names_in_strings_name_existing_modules():
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for line, module, by_string in _uses(path):
            if by_string and not _exists(module):
                missing.append(f"{path.relative_to(ROOT)}:{line}: {module}")
    assert not missing, "strings naming modules that do not exist:\n" + "\n".join(missing)


def test_the_checker_sees_a_string_that_names_a_higher_layer(tmp_path):
    source = tmp_path / "m.py"
    source.write_text('NODE = "feed_twin.ros.twin_node"\nimport feed_twin.core.signals\n')
    assert _uses(source) == [
        (1, "feed_twin.ros.twin_node", True),
        (2, "feed_twin.core.signals", False),
    ]
    assert _layer_of("ros") > _layer_of("machine")
    assert _exists("feed_twin.ros.twin_node") and not _exists("feed_twin.ros.no_such_node")
    assert _exists("feed_twin.plant.backlash.backlash_force")
    assert not _exists("feed_twin.plant.backlash.no_such_function")
