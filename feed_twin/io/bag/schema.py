"""ROS 2 message definitions for recording, found through the ament index without rclpy.

A rosbag2 MCAP file stores, for each message type, a `ros2msg` schema: the type's `.msg` text
followed by one block per nested type it depends on (transitively), each introduced by a line of
80 `=` and `MSG: pkg/Type`. Channels also carry the type's RIHS01 hash, which rosidl writes into
`share/<pkg>/msg/<Type>.json`. Both files are installed by every interface package (the ROS
wheels and the project's own `msgs/`), so this module reads them from the install prefixes:
`AMENT_PREFIX_PATH` when set, plus the running interpreter's prefix (the venv).
"""

from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import dataclass
from functools import cache
from pathlib import Path

DEPENDENCY_SEPARATOR = "=" * 80
PRIMITIVE_TYPES = frozenset(
    {
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    }
)
_TYPE_NAME = re.compile(r"^(?P<pkg>[A-Za-z][A-Za-z0-9_]*)/msg/(?P<name>[A-Z][A-Za-z0-9]*)$")
_ARRAY_SUFFIX = re.compile(r"\[[^\]]*\]$")
_STRING_BOUND = re.compile(r"<=\d+$")


class MessageTypeError(LookupError):
    """A message type is malformed or its definition is not installed."""


@dataclass(frozen=True, kw_only=True)
class MessageDefinition:
    type_name: str  # pkg/msg/Type
    schema_text: str  # ros2msg text: root .msg + dependency blocks
    type_hash: str  # RIHS01_<64 hex>
    dependencies: tuple[str, ...]  # pkg/msg/Type of every nested type, in schema order


def split_type_name(type_name: str) -> tuple[str, str]:
    """`pkg/msg/Type` -> (pkg, Type); anything else raises naming the expected form."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise MessageTypeError(
            f"message type {type_name!r}: expected the form package/msg/Type, "
            "e.g. sensor_msgs/msg/JointState"
        )
    return match["pkg"], match["name"]


def ament_prefixes() -> tuple[Path, ...]:
    """Install prefixes searched for interface packages, in priority order."""
    entries = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    entries.append(sys.prefix)
    seen: list[Path] = []
    for entry in entries:
        path = Path(entry)
        if path not in seen:
            seen.append(path)
    return tuple(seen)


def package_share(package: str) -> Path:
    """The share directory of an installed package, located through the ament index."""
    for prefix in ament_prefixes():
        marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
        if marker.exists():
            return prefix / "share" / package
    searched = ", ".join(str(p) for p in ament_prefixes())
    raise MessageTypeError(
        f"interface package {package!r} is not installed in any ament prefix ({searched})"
    )


def _msg_file(type_name: str, suffix: str) -> Path:
    package, name = split_type_name(type_name)
    path = package_share(package) / "msg" / f"{name}{suffix}"
    if not path.is_file():
        raise MessageTypeError(f"message type {type_name!r}: {path} does not exist")
    return path


def nested_types(msg_text: str, package: str) -> tuple[str, ...]:
    """The non-primitive field types of one .msg text, as pkg/msg/Type, in field order."""
    found: list[str] = []
    for raw in msg_text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        # Constants ("int32 MODE=3") have primitive types, so the type token alone decides.
        type_token = line.split()[0]
        base = _STRING_BOUND.sub("", _ARRAY_SUFFIX.sub("", type_token))
        if base in PRIMITIVE_TYPES:
            continue
        parts = base.split("/")
        if len(parts) == 1:
            full = f"{package}/msg/{parts[0]}"
        elif len(parts) == 2:
            full = f"{parts[0]}/msg/{parts[1]}"
        elif len(parts) == 3 and parts[1] == "msg":
            full = base
        else:
            raise MessageTypeError(f"cannot parse the field type {type_token!r} in {raw!r}")
        if full not in found:
            found.append(full)
    return tuple(found)


@cache
def message_definition(type_name: str) -> MessageDefinition:
    """The ros2msg schema text and RIHS01 hash of an installed message type."""
    root_text = _msg_file(type_name, ".msg").read_text(encoding="utf-8")
    order: list[str] = []
    texts: dict[str, str] = {}

    def visit(name: str, text: str) -> None:
        package, _ = split_type_name(name)
        for dep in nested_types(text, package):
            if dep in texts or dep == type_name:
                continue
            texts[dep] = _msg_file(dep, ".msg").read_text(encoding="utf-8")
            order.append(dep)
            visit(dep, texts[dep])

    visit(type_name, root_text)
    blocks = [root_text.rstrip("\n")]
    for dep in order:
        package, name = split_type_name(dep)
        blocks.append(
            f"{DEPENDENCY_SEPARATOR}\nMSG: {package}/{name}\n{texts[dep].rstrip(chr(10))}"
        )
    return MessageDefinition(
        type_name=type_name,
        schema_text="\n".join(blocks) + "\n",
        type_hash=type_hash(type_name),
        dependencies=tuple(order),
    )


def type_hash(type_name: str) -> str:
    """The RIHS01 type hash rosidl generated for `type_name`."""
    path = _msg_file(type_name, ".json")
    data = json.loads(path.read_text(encoding="utf-8"))
    for entry in data.get("type_hashes", ()):
        if entry.get("type_name") == type_name:
            return str(entry["hash_string"])
    raise MessageTypeError(f"message type {type_name!r}: {path} lists no hash for it")
