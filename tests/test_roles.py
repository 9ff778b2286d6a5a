"""The node-role registry (feed_twin.nodeset.roles) is complete and the only place of its names."""

from __future__ import annotations

import argparse
import ast
import importlib
from pathlib import Path

import pytest

from feed_twin.io import msg_types
from feed_twin.nodeset.roles import COMMON_ARGUMENTS, ROLES, Role, RoleTopic, node_role, roles_where

PACKAGE = Path(__file__).resolve().parents[1] / "feed_twin"
KNOWN_TYPES = {v for k, v in vars(msg_types).items() if k.isupper() and "/msg/" in str(v)}
# the modules allowed to spell a role's topic: the registry and the axis's topic names
TOPIC_SPELLERS = {"nodeset/roles.py", "nodeset/topics.py"}


def _options(role: Role) -> set[str]:
    """The option strings of the role's node command line (common options + its own)."""
    from feed_twin.ros.runtime import node_parser

    module = importlib.import_module(role.module)
    try:
        parser = node_parser(f"{role.name} node", module.configure)
    except argparse.ArgumentError:  # the module declares the common options itself
        parser = argparse.ArgumentParser()
        module.configure(parser)
    return set(parser._option_string_actions)


@pytest.mark.parametrize("name", list(ROLES))
def test_every_role_module_has_its_entry_points_and_arguments(name):
    role = ROLES[name]
    assert role.name == name and role.module.startswith("feed_twin.ros.")
    module = importlib.import_module(role.module)
    assert callable(module.main) and callable(module.configure)
    if role.hostable:
        assert callable(module.build)  # feed_twin/ros/host.py builds it in a shared process
    missing = set(COMMON_ARGUMENTS + role.arguments) - _options(role)
    assert not missing, f"{role.module} does not take {sorted(missing)}"


def test_every_topic_has_a_known_type_and_a_direction():
    for role in ROLES.values():
        for topic in role.topics:
            assert topic.type_name in KNOWN_TYPES, (role.name, topic)
            assert topic.direction in ("publishes", "subscribes")


def test_flags_answer_the_questions_host_and_guard_ask():
    assert roles_where(hostable=True) == ("recorder", "controller", "sim", "gcode")
    assert roles_where(repeatable=True) == ("controller",)
    assert roles_where(guarded=True) == ("controller", "sim")
    assert node_role("machine_linuxcnc").node_name == "linuxcnc"


def test_topic_names_and_types_under_a_namespace():
    twin = node_role("twin")
    assert twin.topic("/cnc/x/twin/", "residual") == "/cnc/x/twin/residual"
    assert twin.topic_types("/cnc/x/twin") == {
        "/cnc/x/twin/state": msg_types.AXIS_STATE,
        "/cnc/x/twin/residual": msg_types.TWIN_RESIDUAL,
        "/cnc/x/twin/health": msg_types.HEALTH_STATUS,
        "/cnc/x/twin/batch": msg_types.RECORD_BATCH,
    }
    assert node_role("sim").topic_types("/cnc/x", "subscribes") == {
        "/cnc/x/drive_command": msg_types.DRIVE_COMMAND,
        "/cnc/x/program_state": msg_types.STRING,
        "/cnc/x/heartbeat": msg_types.STRING,
    }


def test_errors_name_what_is_wrong():
    with pytest.raises(KeyError, match="role 'twin' has no topic 'feedback' \\(its topics: state"):
        node_role("twin").topic("/cnc/x/twin", "feedback")
    with pytest.raises(KeyError, match="node role 'drive': must be one of recorder, controller"):
        node_role("drive")
    with pytest.raises(ValueError, match="name = '/cnc/x/state': must be relative"):
        RoleTopic(name="/cnc/x/state", type_name=msg_types.AXIS_STATE, direction="publishes")
    with pytest.raises(ValueError, match="direction = 'sends': must be publishes or subscribes"):
        RoleTopic(name="state", type_name=msg_types.AXIS_STATE, direction="sends")  # type: ignore[arg-type]


def _spelled_topics(path: Path, names: set[str]) -> list[str]:
    """F-strings ending in `/<name>` and literals `/<ns>/.../<name>`, name a role's topic."""
    tree = ast.parse(path.read_text())
    inside_f = {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
    # Rerun entity paths (`Series(path="/position/command")`) are not topics
    entity = {id(k.value) for n in ast.walk(tree) if isinstance(n, ast.Call) for k in n.keywords}
    entity &= {
        id(k.value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Call)
        for k in n.keywords
        if k.arg in ("path", "origin")
    }
    inside_f |= entity
    # in a module that logs to Rerun, the keys of a dict are entity paths ({"/position/command": x})
    if any(
        isinstance(n, ast.Import | ast.ImportFrom)
        and any(a.name.split(".")[0] == "rerun" for a in n.names)
        or isinstance(n, ast.ImportFrom)
        and (n.module or "").split(".")[0] == "rerun"
        for n in ast.walk(tree)
    ):
        inside_f |= {id(k) for n in ast.walk(tree) if isinstance(n, ast.Dict) for k in n.keys}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr) and len(node.values) > 1:
            last = node.values[-1]
            tail = last.value if isinstance(last, ast.Constant) else None
            hit = isinstance(tail, str) and tail.count("/") == 1 and tail[1:] in names
        elif isinstance(node, ast.Constant) and id(node) not in inside_f:
            tail = node.value
            hit = isinstance(tail, str) and tail.startswith("/") and tail.count("/") >= 2
            hit = hit and isinstance(tail, str) and tail.rpartition("/")[2] in names
        else:
            continue
        if hit:
            found.append(f"{path.name}:{node.lineno}: ...{tail}")
    return found


def test_no_other_module_spells_a_role_topic():
    names = {t.name for role in ROLES.values() for t in role.topics}
    spelled = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.relative_to(PACKAGE).as_posix() not in TOPIC_SPELLERS:
            spelled += _spelled_topics(path, names)
    assert not spelled, "topic names spelled outside the registry:\n" + "\n".join(spelled)


def test_the_speller_finder_sees_an_f_string(tmp_path):
    source = tmp_path / "m.py"
    source.write_text(
        'ns = "/a"\nx = f"{ns}/residual"\ny = "/cnc/x/health"\nz = "residual"\nw = "/health"\n'
    )
    found = _spelled_topics(source, {"residual", "health"})
    assert [f.split(":")[1] for f in found] == ["2", "3"]
