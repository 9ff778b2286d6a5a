"""The bottom layer (feed_twin.core) stands alone; plant and control do not import each other."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "feed_twin"


def _imports(package: str) -> dict[str, set[str]]:
    """Module file -> the feed_twin modules it imports (at any depth of the file)."""
    found: dict[str, set[str]] = {}
    for path in sorted((PACKAGE / package).glob("*.py")):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                names.add(node.module)
                names.update(f"{node.module}.{a.name}" for a in node.names)
            elif isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
        found[path.name] = {n for n in names if n.startswith("feed_twin")}
    return found


def test_core_imports_only_core():
    bad = {
        f: sorted(n for n in names if not n.startswith("feed_twin.core"))
        for f, names in _imports("core").items()
    }
    assert {f: n for f, n in bad.items() if n} == {}
    assert {"signals.py", "trig.py", "smooth.py", "fma.py", "validate.py", "config.py"} <= set(bad)


def test_plant_and_control_do_not_import_each_other():
    plant_to_control = {
        f: sorted(n for n in names if n.startswith("feed_twin.control"))
        for f, names in _imports("plant").items()
    }
    control_to_plant = {
        f: sorted(n for n in names if n.startswith("feed_twin.plant"))
        for f, names in _imports("control").items()
    }
    assert {f: n for f, n in plant_to_control.items() if n} == {}
    assert {f: n for f, n in control_to_plant.items() if n} == {}


def test_plant_components_take_their_validators_from_core():
    uses_loader = {f for f, names in _imports("plant").items() if "feed_twin.core.config" in names}
    # only the YAML loaders of the plant section read feed_twin.core.config
    assert uses_loader <= {"config.py", "plausible.py"}
