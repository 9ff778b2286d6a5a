"""Does LinuxCNC's interpreter accept a program? Asked of the stand-alone `rs274`.

`rs274` is the rs274ngc interpreter of LinuxCNC without motion: with the machine's INI it reads
a program in well under a second and stops at the first block it rejects, printing the message
and the block's text (not its number). LinuxCNC in AUTO reports the same message without any
line, so the runner asks `rs274` first and names the line: the first line of the program whose
text is the rejected block (every earlier copy of it was accepted, so this is exact unless the
same text is rejected only in a later context, e.g. an arc after a modal change).
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from feed_twin.gcode.config import NcConfig
from feed_twin.linuxcnc.machine import INI_NAME, HalServo, write_machine


@dataclass(frozen=True, kw_only=True)
class Rejection:
    """Why LinuxCNC's interpreter rejects a program."""

    path: Path
    line: int | None  # 1-based line number of the rejected block (None: not found)
    message: str  # the interpreter's message, e.g. "Unknown g code used"
    block: str  # the rejected block's text

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line else str(self.path)
        return f"{where}: LinuxCNC rejects '{self.block}': {self.message}"


def linuxcnc_rejects(program: str | Path, nc: NcConfig, servo: HalServo) -> Rejection | None:
    """None when LinuxCNC's interpreter reads the whole program, else why it stops."""
    with tempfile.TemporaryDirectory(prefix="feed_twin-rs274-") as tmp:
        write_machine(tmp, nc, servo)
        return rejection_in(program, Path(tmp))


def rejection_in(program: str | Path, machine_dir: Path) -> Rejection | None:
    """`linuxcnc_rejects` with the machine in `machine_dir` (its INI and parameter file)."""
    program = Path(program)
    rs274 = shutil.which("rs274")
    if rs274 is None:
        raise FileNotFoundError("rs274 (LinuxCNC's stand-alone interpreter) is not on PATH")
    result = subprocess.run(
        [rs274, "-i", INI_NAME, "-g", str(program.resolve()), "canon.txt"],
        cwd=machine_dir, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    (machine_dir / "canon.txt").unlink(missing_ok=True)
    if result.returncode == 0:
        return None
    said = [
        line.strip()
        for line in (result.stderr + "\n" + result.stdout).splitlines()
        if line.strip() and line.strip() != "executing"
    ]
    message = said[0] if said else f"rs274 exited with status {result.returncode}"
    block = said[1] if len(said) > 1 else ""
    return Rejection(path=program, line=_line_of(program, block), message=message, block=block)


def _line_of(program: Path, block: str) -> int | None:
    if not block:
        return None
    for number, text in enumerate(program.read_text(errors="replace").splitlines(), start=1):
        if text.strip() == block:
            return number
    return None
