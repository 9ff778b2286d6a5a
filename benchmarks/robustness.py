"""Robustness of feed_twin under bad input and faults (issue 19): the last line is one JSON object.

A corpus of cases, each run as a user would (the `feed-twin` command in a subprocess):
- programs: malformed G-code through `feed-twin plan` and `feed-twin run`;
- configs: broken, implausible and inconsistent axis configs through `feed-twin model` and
  `feed-twin run`;
- measured inputs: broken CSV records through `feed-twin simulate`;
- bags: truncated and foreign files through `feed-twin bag info/recover`;
- outputs (benchmarks/_robustness_outputs.py): run names that are paths or already used, an
  earlier diagnosis, argument errors, an FMU on a full disk, a machine's read-only --out, a
  vertical axis too heavy for its drive;
- faults, foreign publishers, disks and concurrency (benchmarks/_robustness_runs.py): runs killed
  (runner, node processes), interrupted, stopped by the drive's protection, a disk that fills up
  in a small tmpfs, read-only and missing output directories, foreign and insider publishers
  on the command topics, two runs at once.
A case passes when the outcome is right (the exit code, the one-line error naming what is
wrong, or the correct handling), no traceback is printed, no output is misreported (a path
reported that does not exist or is incomplete) and nothing hangs (each case has a deadline).
After each fault the fraction of the data recovered is measured where it is defined: messages
in the recovered bag over the complete messages an independent stream reader finds in the
file as the fault left it, and for a killed runner, state samples in the bag over the exchanges
the sim node reports.

    .venv/bin/python benchmarks/robustness.py [--skip-runs] [--only NAME_PART]

Needs root for the tmpfs cases (`mount -t tmpfs`); without it they are reported as skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
EMPS = ROOT / "config" / "emps.yaml"
EMPS_MAP = ROOT / "config" / "emps_map.yaml"
EMPS_DATA = Path("/work/shared/data/emps/DATA_EMPS.csv")
CLI = [sys.executable, "-m", "feed_twin.cli"]
CLI_TIMEOUT_S = 120.0


@dataclass
class Outcome:
    passed: bool
    detail: str
    recovered: float | None = None  # fraction of the flushed data recovered after a fault


@dataclass
class Case:
    name: str
    kind: str  # program | config | measured | bag | fault | foreign | disk | concurrent
    check: Callable[[Path], Outcome]


def cli(args: list[str], *, env: dict | None = None, timeout: float = CLI_TIMEOUT_S):
    """(exit code, stdout, stderr) of one `feed-twin` command; code None when it hung."""
    try:
        done = subprocess.run(
            [*CLI, *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env
        )
    except subprocess.TimeoutExpired:
        return None, "", f"hung for more than {timeout:g} s"
    return done.returncode, done.stdout, done.stderr


def one_line_error(args: list[str], code: int, needle: str, **kw) -> Outcome:
    """The command fails with `code`, one line on stderr containing `needle`, no traceback,
    and (for `run`) no output reported."""
    rc, out, err = cli(args, **kw)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    problems = []
    if rc != code:
        problems.append(f"exit {rc}, expected {code}")
    if len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr")
    if "Traceback" in err:
        problems.append("traceback")
    if needle not in err:
        problems.append(f"no {needle!r} in the message")
    if "bag: /" in out or "rerun: /" in out:
        problems.append("reports outputs")
    first = lines[0][:160] if lines else ""
    return Outcome(not problems, "; ".join(problems) or first)


# -- programs ----------------------------------------------------------------------------------

PROGRAMS: dict[str, tuple[bytes, str]] = {
    # name: (program bytes, what the message must contain)
    "empty": (b"", "empty"),
    "only_percent": (b"%\n%\n", "empty"),
    "binary": (bytes(range(256)) * 4, "not a text G-code file"),
    "nul_byte": (b"G1 X1\x00 F100\n", "NUL"),
    "bad_utf8": (b"G1 X1 F100 (\xff)\n", "invalid UTF-8"),
    "unknown_g": (b"G21 G90 G54\nG93.5 X1\n", "G93.5"),
    "bad_number": (b"G21 G90 G54\nG1 X1.2.3 F100\n", ":2:"),
    "letter_only": (b"G21 G90 G54\nG1 X F100\n", ":2:"),
    "feed_missing": (b"G21 G90 G54\nG1 X10\n", "feed"),
    "unclosed_comment": (b"G21 G90 G54\nG1 X1 (comment F100\n", ":2:"),
    "arc_no_center": (b"G21 G90 G54 G17\nG2 X10 Y0 F100\n", ":2:"),
    "arc_radius_mismatch": (b"G21 G90 G54 G17\nG2 X10 Y0 I1 J0 F100\n", ":2:"),
    "beyond_travel": (b"G21 G90 G54\nG1 X5000 F1000\n", "travel"),
    "two_motion_groups": (b"G21 G90 G54\nG0 G1 X1 F100\n", ":2:"),
    "long_line": (b"G1 X" + b"1" * 2_000_000 + b"\n", "longer than 4096 bytes"),
    "long_word_echo": (b"G21 G90 G54\nG1 X" + b"9" * 3000 + b" F100\n", "characters)"),
    "negative_feed": (b"G21 G90 G54\nG1 X1 F-100\n", ":2:"),
    "dwell_negative": (b"G21 G90 G54\nG4 P-1\n", ":2:"),
}


def program_case(name: str, via: str) -> Case:
    data, needle = PROGRAMS[name]

    def check(work: Path) -> Outcome:
        program = work / f"{name}.ngc"
        program.write_bytes(data)
        if via == "plan":
            return one_line_error(["plan", str(program), "--config", str(AXIS)], 2, needle)
        out = work / f"out_{name}"
        return one_line_error(
            ["run", str(program), "--config", str(AXIS), "--out", str(out)], 1, needle
        )

    return Case(f"program_{via}_{name}", "program", check)


# -- configs -----------------------------------------------------------------------------------


def _axis(edit: Callable[[dict], None]) -> bytes:
    data = yaml.safe_load(AXIS.read_text())
    edit(data)
    return yaml.safe_dump(data).encode()


def _component(data: dict, name: str) -> dict:
    return next(c for c in data["plant"]["components"] if c["name"] == name)["params"]


CONFIGS: dict[str, tuple[bytes | None, str]] = {
    # name: (file bytes; None: no file at all, a directory for "directory"), message needle
    "missing_file": (None, "no such config file"),
    "empty": (b"", "the file is empty"),
    "not_mapping": (b"- 1\n- 2\n", "must be a mapping"),
    "invalid_yaml": (b"plant: [\n", "invalid YAML"),
    "binary": (bytes(range(256)) * 8, "not a text file"),
    "huge": (b"a: [" + b"1, " * 1_500_000 + b"1]\n", "larger than 4 MB"),
    "unknown_section": (_axis(lambda d: d.update(extra={})), "unknown section(s) extra"),
    "negative_mass": (
        _axis(lambda d: _component(d, "table").update(m=-3.0)),
        "plant.table.m = -3.0: must be > 0",
    ),
    "mass_1e300": (
        _axis(lambda d: _component(d, "table").update(m=1e300)),
        "plant.table.m = 1e+300: implausible",
    ),
    "mass_1e-30": (
        _axis(lambda d: _component(d, "table").update(m=1e-30)),
        "plant.table.m = 1e-30: implausible",
    ),
    "unknown_param": (
        _axis(lambda d: _component(d, "table").update(mass=3.0)),
        "unknown key(s) mass",
    ),
    "unknown_component": (
        _axis(
            lambda d: d["plant"]["components"].append({"name": "z", "type": "Foo", "params": {}})
        ),
        "unknown component type",
    ),
    "nan_value": (
        _axis(lambda d: _component(d, "motor").update(R_s=float("nan"))),
        "plant.motor.R_s",
    ),
    "string_value": (
        _axis(lambda d: _component(d, "motor").update(R_s="abc")),
        "plant.motor.R_s = 'abc': expected a number",
    ),
    "rapid_unreachable": (
        _axis(lambda d: d["nc"]["axes"][0].update(rapid_m_s=0.5)),
        "nc.axes[X].rapid_m_s = 0.5: the motor needs 401 V",
    ),
    "current_unreachable": (
        _axis(lambda d: d["controller"]["drive"].update(effort_limit=3.0)),
        "above controller.drive.effort_limit = 3.0 A",
    ),
    "speed_limit_below_rapid": (
        _axis(lambda d: d["ros"].update(protection={"speed_limit_m_s": 0.3})),
        "above the drive's speed limit",
    ),
    "bad_boundary": (_axis(lambda d: d["ros"].update(boundary="magic")), "ros.boundary"),
    "negative_exchange": (
        _axis(lambda d: d["ros"].update(exchange_period_s=-1.0)),
        "ros.exchange_period_s = -1.0",
    ),
    "negative_gain": (
        _axis(lambda d: d["controller"]["position"].update(Kv_1_s=-30.0)),
        "controller.position.Kv_1_s = -30.0",
    ),
    "bad_connection": (
        _axis(lambda d: d["plant"]["connect"].append(["table.nope", "guides.flange"])),
        "nope",
    ),
    "directory": (None, "is a directory"),
}
RUN_ONLY = {"rapid_unreachable", "current_unreachable", "speed_limit_below_rapid",
            "bad_boundary", "negative_exchange", "negative_gain"}  # fmt: skip


def config_case(name: str, via: str) -> Case:
    data, needle = CONFIGS[name]

    def check(work: Path) -> Outcome:
        path = work / f"cfg_{name}.yaml"
        if name == "directory":
            path.mkdir(exist_ok=True)
        elif data is not None:
            path.write_bytes(data)
        if via == "model":
            return one_line_error(["model", "--config", str(path)], 2, needle)
        program = work / "cfg_move.ngc"
        program.write_text("G21 G90 G54\nG1 X10 F3000\nM30\n")
        out = work / f"out_cfg_{name}"
        return one_line_error(
            ["run", str(program), "--config", str(path), "--out", str(out)], 1, needle
        )

    return Case(f"config_{via}_{name}", "config", check)


# -- measured inputs ---------------------------------------------------------------------------


def _measured_rows(n: int) -> list[str]:
    with open(EMPS_DATA) as f:
        return [next(f) for _ in range(n + 1)]


MEASURED: dict[str, tuple[Callable[[list[str]], str], str]] = {
    "empty": (lambda rows: "", "empty"),
    "header_only": (lambda rows: rows[0], "has a header (5 columns) but no data rows"),
    "missing_column": (
        lambda rows: "".join(",".join(r.split(",")[:2]) + "\n" for r in rows),
        "that the file lacks",
    ),
    "text_in_numbers": (
        lambda rows: rows[0] + "".join(rows[1:500]) + "abc,0.1,1,2,3\n" + "".join(rows[501:]),
        ":501: time column 't_s' is empty or not a number",
    ),
    "nan_values": (
        lambda rows: rows[0] + "".join(r.replace(r.split(",")[2], "nan", 1) for r in rows[1:]),
        "holds no numbers",
    ),
    "time_backwards": (
        lambda rows: rows[0] + "".join(reversed(rows[1:])),
        ":3: time column 't_s' goes back from",
    ),
    "short_rows": (
        lambda rows: rows[0] + "".join(rows[1:100]) + "1.0,2.0\n" + "".join(rows[101:]),
        "line 101 has 2 cells but the header has 5 columns",
    ),
    "binary": (lambda rows: "\x00\x01\x02" * 1000, "is not a text CSV (binary data at byte 0)"),
    "absurd_position": (
        lambda rows: (
            rows[0]
            + "".join(
                ",".join([r.split(",")[0], "1e9", *r.split(",")[2:]]) if i == 700 else r
                for i, r in enumerate(rows[1:])
            )
        ),
        "spans 1e+09 m",
    ),
}


def measured_case(name: str) -> Case:
    make, needle = MEASURED[name]

    def check(work: Path) -> Outcome:
        path = work / f"measured_{name}.csv"
        path.write_text(make(_measured_rows(1500)))
        return one_line_error(
            ["simulate", "--config", str(EMPS), "--measured", str(path), "--map", str(EMPS_MAP),
             "--out", str(work / f"sim_{name}.csv")],
            2, needle,
        )  # fmt: skip

    return Case(f"measured_{name}", "measured", check)


# -- bags --------------------------------------------------------------------------------------


def bag_garbage(work: Path) -> Outcome:
    bag = work / "garbage_bag"
    bag.mkdir(exist_ok=True)
    (bag / "garbage_bag_0.mcap").write_bytes(os.urandom(50_000))
    return one_line_error(["bag", "recover", str(bag)], 1, "nothing recoverable")


def bag_missing(work: Path) -> Outcome:
    return one_line_error(["bag", "info", str(work / "no_such_bag")], 1, "no_such_bag")


def plan_broken_pipe(work: Path) -> Outcome:
    cmd = (
        f"{sys.executable} -m feed_twin.cli plan tests/fixtures/gcode/sample.ngc --config "
        f"{AXIS} --out /dev/stdout | head -n 1 > /dev/null; echo ${{PIPESTATUS[0]}}"
    )
    done = subprocess.run(
        ["bash", "-c", cmd], capture_output=True, text=True, cwd=ROOT, timeout=CLI_TIMEOUT_S
    )
    ok = done.stdout.strip() == "141" and not done.stderr.strip()
    return Outcome(ok, f"exit {done.stdout.strip()}, stderr {done.stderr.strip()[:80]!r}")


def input_cases() -> list[Case]:
    cases = [program_case(n, "plan") for n in PROGRAMS]
    cases += [program_case(n, "run") for n in ("binary", "long_line", "unknown_g", "feed_missing")]
    cases += [config_case(n, "model") for n in CONFIGS if n not in RUN_ONLY]
    cases += [config_case(n, "run") for n in CONFIGS]
    cases += [measured_case(n) for n in MEASURED]
    cases += [
        Case("bag_recover_garbage", "bag", bag_garbage),
        Case("bag_info_missing", "bag", bag_missing),
        Case("plan_into_closed_pipe", "program", plan_broken_pipe),
    ]
    return cases


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--skip-runs", action="store_true", help="input cases only")
    parser.add_argument("--only", default="", help="run the cases whose name contains this")
    args = parser.parse_args()
    cases = input_cases()
    sys.path.insert(0, str(Path(__file__).parent))
    from _robustness_outputs import output_cases

    cases += output_cases()
    if not args.skip_runs:
        from _robustness_runs import run_cases

        cases += run_cases()
    cases = [c for c in cases if args.only in c.name]
    results = []
    with tempfile.TemporaryDirectory(prefix="feed_twin_robustness_") as tmp:
        work = Path(tmp)
        for case in cases:
            started = time.monotonic()
            try:
                outcome = case.check(work)
            except Exception as exc:  # noqa: BLE001 - a broken case is a failed case, not a stop
                outcome = Outcome(False, f"the case itself failed: {type(exc).__name__}: {exc}")
            took = time.monotonic() - started
            mark = "pass" if outcome.passed else "FAIL"
            extra = f" recovered {outcome.recovered:.4f}" if outcome.recovered is not None else ""
            print(f"{mark} {case.kind:<10} {case.name:<40} {took:6.1f} s{extra}  {outcome.detail}")
            results.append((case, outcome))
    recovered = [o.recovered for _, o in results if o.recovered is not None]
    by_kind: dict[str, list[int]] = {}
    for case, outcome in results:
        tried_passed = by_kind.setdefault(case.kind, [0, 0])
        tried_passed[0] += 1
        tried_passed[1] += outcome.passed
    summary = {
        "cases_tried": len(results),
        "cases_passed": sum(o.passed for _, o in results),
        "failed": [c.name for c, o in results if not o.passed],
        "by_kind": {k: {"tried": v[0], "passed": v[1]} for k, v in sorted(by_kind.items())},
        "recovered_fraction_min": min(recovered) if recovered else None,
        "recovered_fraction_mean": sum(recovered) / len(recovered) if recovered else None,
        "recovery_cases": len(recovered),
    }
    print(
        f"cases tried {summary['cases_tried']}, passed {summary['cases_passed']}; recovered "
        f"fraction min {summary['recovered_fraction_min']} over {len(recovered)} fault cases"
    )
    print(json.dumps(summary))
    return 0 if summary["cases_passed"] == summary["cases_tried"] else 1


if __name__ == "__main__":
    sys.exit(main())
