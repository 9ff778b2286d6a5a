"""Check the .msg files of an interface package before CMake sees them.

rosidl reports a syntax error without the file or the line, buried in a CMake trace. This check
parses each message with rosidl's own parser, one line more at a time, so the first line that
breaks it is named as `path:line: text: reason`. It also rejects field types that neither the
package nor an installed package defines, and .msg files the CMakeLists.txt does not list.

Usage: python tools/check_msgs.py MSGS_DIR PREFIX   (PREFIX: where the dependencies are installed)
Exit status 0 when all is well, 1 with one line per problem on stderr otherwise.
"""

from __future__ import annotations

import contextlib
import io
import re
import sys
from pathlib import Path

from rosidl_adapter.parser import BaseType, parse_message_string


def _parse(package: str, name: str, text: str):
    # The parser also prints each error to stderr; the caller reports it once, with its line.
    with contextlib.redirect_stderr(io.StringIO()):
        return parse_message_string(package, name, text)


def _first_bad_line(package: str, name: str, lines: list[str]) -> tuple[int, str]:
    """1-based number and reason of the first line at which the message stops parsing."""
    for count in range(1, len(lines) + 1):
        try:
            _parse(package, name, "\n".join(lines[:count]))
        except Exception as exc:  # rosidl raises several unrelated exception types
            return count, str(exc) or type(exc).__name__
    return 0, ""


def _field_line(lines: list[str], field_name: str) -> int:
    pattern = re.compile(rf"^\s*\S+\s+{re.escape(field_name)}(\s|=|$)")
    for number, line in enumerate(lines, start=1):
        if pattern.match(line):
            return number
    return 0


def check_package(msgs_dir: Path, prefix: Path) -> list[str]:
    """Problems found in the package at msgs_dir, each as one `path:line: ...` string."""
    problems: list[str] = []
    package = re.search(r"<name>\s*([^<\s]+)\s*</name>", (msgs_dir / "package.xml").read_text())
    package_name = package.group(1) if package else msgs_dir.name
    msg_files = sorted((msgs_dir / "msg").glob("*.msg"))
    own_types = {path.stem for path in msg_files}

    cmake = (msgs_dir / "CMakeLists.txt").read_text()
    listed = set(re.findall(r'"msg/([A-Za-z0-9_]+)\.msg"', cmake))
    for path in msg_files:
        if path.stem not in listed:
            problems.append(f"{path}:1: not listed in rosidl_generate_interfaces of {msgs_dir}")
    for stem in sorted(listed - own_types):
        problems.append(f"{msgs_dir / 'CMakeLists.txt'}:1: lists msg/{stem}.msg, which is absent")

    for path in msg_files:
        text = path.read_text()
        lines = text.splitlines()
        try:
            spec = _parse(package_name, path.stem, text)
        except Exception:
            number, reason = _first_bad_line(package_name, path.stem, lines)
            shown = lines[number - 1].strip() if number else ""
            problems.append(f"{path}:{number}: {shown}: {reason}")
            continue
        for field in spec.fields:
            if field.type.is_primitive_type():
                continue
            base = BaseType(BaseType.__str__(field.type))
            # parsed without a context package, a non-primitive type always names its own
            assert base.pkg_name is not None, f"{path}: {field.name}: a type without a package"
            known = (base.pkg_name == package_name and base.type in own_types) or (
                prefix / "share" / base.pkg_name / "msg" / f"{base.type}.msg"
            ).is_file()
            if not known:
                number = _field_line(lines, field.name)
                shown = lines[number - 1].strip() if number else field.name
                problems.append(
                    f"{path}:{number}: {shown}: unknown message type "
                    f"'{base.pkg_name}/{base.type}' (not in {package_name} nor in {prefix})"
                )
    return problems


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: check_msgs.py MSGS_DIR PREFIX", file=sys.stderr)
        return 2
    problems = check_package(Path(argv[0]), Path(argv[1]))
    for problem in problems:
        print(problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
