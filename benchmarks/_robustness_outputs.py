"""Cases of benchmarks/robustness.py about what a command writes (issue 29): run names that
are paths or already used, an earlier diagnosis, argument errors, an FMU on a full disk, a
machine's read-only --out and a vertical axis too heavy for its drive."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import yaml
from _robustness_runs import tmpfs
from robustness import AXIS, ROOT, Case, Outcome, cli, one_line_error

MACHINE = ROOT / "config" / "machine_default.yaml"
NOMINAL = ROOT / "config" / "emps_nominal.yaml"
MOVE = "G21 G90\nG1 X1 Z1 F3000\nM2\n"


def _program(work: Path) -> Path:
    path = work / "move29.ngc"
    path.write_text(MOVE)
    return path


def _digest(directory: Path) -> dict[str, str]:
    return {
        str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def name_is_a_path(config: Path):
    def check(work: Path) -> Outcome:
        out = work / "names" / "out"
        outcome = one_line_error(
            ["run", str(_program(work)), "--config", str(config), "--out", str(out),
             "--name", "../../escaped"],
            1, "must be a file name inside --out, not a path",
        )  # fmt: skip
        escaped = [p.name for p in work.rglob("escaped*")]
        if escaped:
            return Outcome(False, f"wrote {escaped} outside --out")
        return outcome

    return check


def name_used_twice(work: Path) -> Outcome:
    """A machine run in-process, then a second one with the same --name."""
    out = work / "twice"
    args = ["run", str(_program(work)), "--config", str(MACHINE), "--in-process", "--out",
            str(out), "--name", "same"]  # fmt: skip
    rc, _, err = cli(args)
    if rc != 0:
        return Outcome(False, f"the first run failed: exit {rc} {err.strip()[:120]}")
    before = _digest(out)
    outcome = one_line_error(args, 1, "--name same: already used in")
    if _digest(out) != before:
        return Outcome(False, "the second run changed the first run's outputs")
    return outcome


def diagnose_keeps_a_report(work: Path) -> Outcome:
    out = work / "diagnosed"
    out.mkdir(exist_ok=True)
    (out / "report.md").write_text("an earlier report")
    outcome = one_line_error(
        ["diagnose", "x.csv", "--config", str(NOMINAL), "--out", str(out)], 2,
        "holds a report already (report.md)",
    )  # fmt: skip
    if (out / "report.md").read_text() != "an earlier report":
        return Outcome(False, "the earlier report was replaced")
    return outcome


def argument_error(work: Path) -> Outcome:
    return one_line_error(
        ["run", str(_program(work)), "--no-such-option"], 2, "unrecognized arguments"
    )


def fmu_full_disk(work: Path) -> Outcome:
    with tmpfs(work / "fmu_small", "200k") as small:
        outcome = one_line_error(
            ["fmu", "--config", str(AXIS), "--out", str(small / "a.fmu")], 2,
            "No space left on device",
        )  # fmt: skip
        left = [p.name for p in small.iterdir()]
    return Outcome(False, f"left {left}") if left else outcome


def machine_read_only_out(work: Path) -> Outcome:
    with tmpfs(work / "machine_ro", "1m", read_only=True) as ro:
        return one_line_error(
            ["run", str(_program(work)), "--config", str(MACHINE), "--in-process", "--out",
             str(ro / "bags")],
            1, "Read-only file system",
        )  # fmt: skip


def heavy_vertical(work: Path) -> Outcome:
    raw = yaml.safe_load(MACHINE.read_text())
    for entry in raw["axes"].values():
        entry["include"] = str(AXIS)
    raw["axes"]["Z"]["vertical"]["m_kg"] = 6000.0
    path = work / "heavy_machine.yaml"
    path.write_text(yaml.safe_dump(raw))
    return one_line_error(
        ["run", str(_program(work)), "--config", str(path), "--in-process", "--out",
         str(work / "heavy")],
        1, "holding a static load of 57340 N",
    )  # fmt: skip


def output_cases() -> list[Case]:
    cases = [
        Case("run_name_is_a_path", "names", name_is_a_path(AXIS)),
        Case("machine_run_name_is_a_path", "names", name_is_a_path(MACHINE)),
        Case("run_name_used_twice", "names", name_used_twice),
        Case("diagnose_keeps_an_earlier_report", "names", diagnose_keeps_a_report),
        Case("argument_error_one_line", "program", argument_error),
        Case("machine_vertical_too_heavy", "config", heavy_vertical),
    ]
    if os.geteuid() == 0:
        cases += [
            Case("fmu_on_a_full_disk", "disk", fmu_full_disk),
            Case("machine_read_only_out", "disk", machine_read_only_out),
        ]
    return cases
