"""The core never touches ROS: no module outside feed_twin/ros/ imports rclpy, a generated
message package or feed_twin.ros, neither in its source (AST scan) nor at import time
(sys.modules check)."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import feed_twin

PACKAGE_DIR = Path(feed_twin.__file__).resolve().parent
ROS_DIR = PACKAGE_DIR / "ros"

# rclpy and its C layers, the rosidl machinery, every generated interface package, and the
# node shells themselves (the core may not depend on feed_twin.ros, even on a pure module there).
_ROS_MODULE = re.compile(r"^(rclpy|rcl|rmw|rosidl\w*|\w+_msgs|\w+_interfaces|feed_twin\.ros)(\.|$)")


def _core_files() -> list[Path]:
    return sorted(p for p in PACKAGE_DIR.rglob("*.py") if ROS_DIR not in p.parents)


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def ros_imports(source: str, filename: str) -> list[str]:
    """`file:line: module` for each import of a ROS module in the source, including
    importlib.import_module("...") and __import__("...") with a literal name."""
    found = []
    for node in ast.walk(ast.parse(source, filename=filename)):
        if not isinstance(node, (ast.stmt, ast.expr)):  # imports and calls: with a line
            continue
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args:
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            first = node.args[0]
            if called in ("import_module", "__import__") and isinstance(first, ast.Constant):
                names = [str(first.value)]
        found += [f"{filename}:{node.lineno}: {name}" for name in names if _ROS_MODULE.match(name)]
    return found


def test_the_scan_finds_every_kind_of_ros_import():
    source = textwrap.dedent(
        """
        import os
        import rclpy.node
        from sensor_msgs.msg import JointState
        from feed_twin_msgs.msg import AxisState
        import rosidl_runtime_py
        from rcl_interfaces.msg import Log
        import importlib
        importlib.import_module("std_msgs.msg")
        __import__("rclpy")
        from feed_twin.io import config
        import numpy as np
        """
    )
    assert ros_imports(source, "x.py") == [
        "x.py:3: rclpy.node",
        "x.py:4: sensor_msgs.msg",
        "x.py:5: feed_twin_msgs.msg",
        "x.py:6: rosidl_runtime_py",
        "x.py:7: rcl_interfaces.msg",
        "x.py:9: std_msgs.msg",
        "x.py:10: rclpy",
    ]


def test_no_core_module_imports_ros_in_its_source():
    files = _core_files()
    assert PACKAGE_DIR / "cli.py" in files and PACKAGE_DIR / "core" / "config.py" in files
    assert not any(ROS_DIR in p.parents for p in files)
    offending = []
    for path in files:
        offending += ros_imports(path.read_text(), str(path.relative_to(PACKAGE_DIR.parent)))
    assert offending == [], "only feed_twin/ros/ may import ROS modules:\n" + "\n".join(offending)


@pytest.mark.slow  # imports the whole core (numba, scipy) in a fresh interpreter
def test_importing_every_core_module_loads_no_ros_module():
    modules = [_module_name(p) for p in _core_files()]
    probe = textwrap.dedent(
        """
        import importlib, json, re, sys
        pattern = re.compile(sys.argv[1])
        report = {}
        for name in sys.argv[2:]:
            before = set(sys.modules)
            try:
                importlib.import_module(name)
            except Exception as exc:
                report[name] = f"import failed: {type(exc).__name__}: {exc}"
                continue
            loaded = sorted(m for m in set(sys.modules) - before if pattern.match(m))
            if loaded:
                report[name] = loaded
        print(json.dumps(report))
        """
    )
    result = subprocess.run(
        [sys.executable, "-c", probe, _ROS_MODULE.pattern, *modules],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report == {}, f"core modules that load ROS modules or fail to import: {report}"


def test_the_import_probe_sees_a_ros_import():
    # The same probe flags the ROS shell itself, so an empty report above is not vacuous.
    result = subprocess.run(
        [sys.executable, "-c", "import sys, feed_twin.ros.msgcheck; print('rclpy' in sys.modules)"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert result.stdout.strip() == "True"
