"""Our planner against LinuxCNC's: the same programs with the same limits, measured alike.

Each program of the corpus (tests/fixtures/gcode/peer/*.ngc) runs
- on LinuxCNC 2.9 (feed_twin.linuxcnc: the machine generated from the config's `nc:` section,
  every servo period recorded; its commanded joint positions are the trajectory),
- through feed_twin.gcode with the config's profile ('jerk') and with 'trapezoid' (LinuxCNC's
  planner is acceleration-limited, not jerk-limited),
and all three are measured against the programmed path by feed_twin.gcode.metrics: program time,
distance from the path (max, RMS), corner deviation and speed, arc distance from the programmed
circle, peak velocity/acceleration/jerk per axis (differences of the positions, both sides).

Requirements checked on our sides: arc samples within chord_tolerance_m of the circle, blended
corners within their G64 tolerance; every axis's peak velocity and acceleration (and, for the
jerk profile, jerk) from differences of the sampled positions within its limits; the
trapezoid's program time within 5 % of LinuxCNC's and the jerk profile's at most 1.10 times
LinuxCNC's (LinuxCNC is acceleration-limited: a jerk limit may cost a little time, not more).
Beside them the floor of the jerk profile's time (`feed_twin.gcode.jerk_floor`): the
trapezoid's time plus what the jerk limit must add at each of its near-stops (the closed form
of a jerk-limited stop-and-go against an acceleration-limited one), computed from our own plan
alone: how far the jerk profile is from what the limits allow, and how far that is from 1.10.
The programs in peer/disagree/ are accepted by one side only: they are reported, as a program
one side refuses must never silently run on the other. Last printed line: one JSON object with
every figure. Exit status 1 when a requirement is broken.

    .venv/bin/python benchmarks/linuxcnc_peer.py [--config config/axis_default.yaml] [-k NAME]
        [--linuxcnc-cache DIR]

With --linuxcnc-cache DIR, LinuxCNC's trajectory of each program is saved there
(`NAME.npz`, keyed by the program text and what LinuxCNC's run reads: the generated machine's
files, the blend tolerance and the servo; not the jerk limit or the profile) and reused while
neither changes: LinuxCNC takes about 5 min for the corpus (one run at a time per host), and
while our planner changes LinuxCNC's side does not.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from feed_twin.gcode import GcodeError, NcConfig, SampledTrajectory, plan_program
from feed_twin.gcode.geometry import programmed_path
from feed_twin.gcode.jerk_floor import jerk_floor_extra
from feed_twin.gcode.metrics import axis_limit_failures
from feed_twin.gcode.peer import (
    JERK_TIME_LIMIT,
    TIME_TOLERANCE,
    Side,
    acceptance_mismatch,
    measure_side,
    side_summary,
    time_ratio,
)
from feed_twin.linuxcnc.host import LinuxcncError
from feed_twin.linuxcnc.machine import INI_NAME, HalServo, machine_for_config, write_machine
from feed_twin.linuxcnc.runner import RunOptions, run_program

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "fixtures" / "gcode" / "peer"
UM = 1e6
START_FAILURE = "LinuxCNC did not start"
MM = 1e3


def ours(program: Path, nc: NcConfig) -> SampledTrajectory | str:
    try:
        return plan_program(program, nc)
    except GcodeError as exc:
        return str(exc)


def peer_machine(directory: Path, nc: NcConfig, servo: HalServo) -> Path:
    """The generated LinuxCNC machine with [TRAJ]'s vector limits lifted out of the way.

    [TRAJ] MAX_LINEAR_VELOCITY/ACCELERATION cap the speed and acceleration along the path; the
    generated machine sets them to the largest axis limit, so a diagonal rapid runs at 0.5 m/s
    on LinuxCNC and at 0.5 sqrt(2) m/s on feed_twin.gcode, which limits each axis only. At
    sqrt(3) times the largest axis limit only the per-axis limits bind, on both sides.
    """
    write_machine(directory, nc, servo)
    ini = directory / INI_NAME
    lift = math.sqrt(3.0) * 1e3  # [mm/m] LinuxCNC's units are mm
    limits = {
        "VELOCITY": lift * max(a.rapid_m_s for a in nc.axes),
        "ACCELERATION": lift * max(a.a_max_m_s2 for a in nc.axes),
    }
    text = ini.read_text(encoding="utf-8")
    for kind, value in limits.items():
        text, count = re.subn(
            rf"^((?:MAX|DEFAULT)_LINEAR_{kind}) = .*$", rf"\1 = {value:.3f}", text, flags=re.M
        )
        if count != 2:
            raise RuntimeError(f"{ini}: expected MAX_ and DEFAULT_LINEAR_{kind}, found {count}")
    ini.write_text(text, encoding="utf-8")
    return directory


def linuxcnc(
    program: Path, nc: NcConfig, servo: HalServo, machine: Path
) -> SampledTrajectory | str:
    options = RunOptions(machine_dir=machine)
    result = None
    for attempt in (1, 2):
        try:
            result = run_program(program, nc=nc, servo=servo, options=options, say=print)
            break
        except LinuxcncError as exc:
            # A start-up failure says nothing about the program: say so and try once more.
            if attempt == 2 or not str(exc).startswith(START_FAILURE):
                return str(exc)
            print(f"{program.name}: {exc}; starting LinuxCNC again")
    assert result is not None, "the loop ends with a run or returns the second failure"
    if result.trace.samples_lost or result.overruns:
        return f"{result.trace.samples_lost + result.overruns} servo periods lost from the record"
    # From the program's first motion to its last (before it: HAL start-up and homing).
    trace = result.trace.cut(result.trace.program_span())
    return trace.commanded_trajectory(nc.axis_names)


def cache_key(program: Path, nc: NcConfig, servo: HalServo, machine: Path) -> str:
    """What LinuxCNC's run depends on: the program's text, the machine's files as
    `peer_machine` wrote them (limits, travel, home, work offsets, servo), the blend tolerance
    the runner sets (G64 P Q), the axes it records and the servo (its period times the run).
    Not the rest of `nc`: LinuxCNC 2.9 has no jerk limit, and our profile is ours alone, so a
    change of either keeps the cached runs."""
    digest = hashlib.sha256()
    parts = [program.read_bytes()]
    for file in sorted(machine.iterdir()):
        parts += [file.name.encode(), file.read_bytes()]
    parts.append(repr((nc.path_tolerance_m, nc.axis_names, servo)).encode())
    for part in parts:  # each part's length first: no two different splits hash alike
        digest.update(len(part).to_bytes(8, "little") + part)
    return digest.hexdigest()


def cached_linuxcnc(
    program: Path, nc: NcConfig, servo: HalServo, machine: Path, cache: Path | None
) -> SampledTrajectory | str:
    """LinuxCNC's trajectory (or its refusal), from `cache` when it holds this run (refusals
    and failed runs are not saved: a refusal is found before LinuxCNC starts)."""
    if cache is None:
        return linuxcnc(program, nc, servo, machine)
    file = cache / f"{program.stem}.npz"
    key = cache_key(program, nc, servo, machine)
    if file.exists():
        with np.load(file, allow_pickle=False) as data:
            if str(data["key"]) == key:
                return SampledTrajectory(
                    t_s=data["t_s"],
                    axes=tuple(str(a) for a in data["axes"]),
                    pos_m=data["pos_m"],
                    vel_m_s=data["vel_m_s"],
                    acc_m_s2=data["acc_m_s2"],
                    line=data["line"],
                    events=(),
                )
    result = linuxcnc(program, nc, servo, machine)
    if not isinstance(result, str):
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(
            file,
            key=key,
            t_s=result.t_s,
            axes=np.array(result.axes),
            pos_m=result.pos_m,
            vel_m_s=result.vel_m_s,
            acc_m_s2=result.acc_m_s2,
            line=result.line,
        )
    return result


def jerk_floor(trapezoid: SampledTrajectory | str, side: Side, nc: NcConfig) -> dict | None:
    """The floor of the jerk profile's time (`feed_twin.gcode.jerk_floor`): the trapezoid's
    time plus what the jerk limit must add at its near-stops."""
    if isinstance(trapezoid, str) or side.figures is None:
        return None
    extra, stops = jerk_floor_extra(trapezoid, np.array(nc.a_max), np.array(nc.j_max))
    return {"time_s": side.figures.program_time_s + extra, "extra_s": extra, "near_stops": stops}


def run_one(
    program: Path, nc: NcConfig, servo: HalServo, machine: Path, cache: Path | None = None
) -> dict:
    """The three sides of one program, measured, with the requirements and the time ratios."""
    results = {
        "linuxcnc": cached_linuxcnc(program, nc, servo, machine, cache),
        "jerk": ours(program, dataclasses.replace(nc, profile="jerk")),
        "trapezoid": ours(program, dataclasses.replace(nc, profile="trapezoid")),
    }
    try:
        segments = programmed_path(program, nc)
    except GcodeError:
        segments = ()
    sides: list[Side] = []
    for name, result in results.items():
        if segments or isinstance(result, str):
            sides.append(
                measure_side(name, result, segments, chord_tolerance_m=nc.chord_tolerance_m)
            )
        else:
            sides.append(Side(name=name, error=None, figures=None, failures=()))
    by_name = {s.name: s for s in sides}
    floor = jerk_floor(results["trapezoid"], by_name["trapezoid"], nc)
    ratio_trap = time_ratio(by_name["trapezoid"], by_name["linuxcnc"])
    ratio_jerk = time_ratio(by_name["jerk"], by_name["linuxcnc"])
    # The requirements are ours to meet; what LinuxCNC breaks is reported as a finding.
    problems = [f"{s.name}: {text}" for s in sides if s.name != "linuxcnc" for text in s.failures]
    findings = list(by_name["linuxcnc"].failures)
    if ratio_trap is not None and abs(ratio_trap - 1.0) > TIME_TOLERANCE:
        problems.append(
            f"trapezoid program time {ratio_trap:.3f} x LinuxCNC's (limit 1 +- {TIME_TOLERANCE})"
        )
    if ratio_jerk is not None and ratio_jerk > JERK_TIME_LIMIT:
        problems.append(
            f"jerk program time {ratio_jerk:.3f} x LinuxCNC's (limit {JERK_TIME_LIMIT})"
        )
    v_top = tuple(max(v, r) for v, r in zip(nc.v_max, nc.rapid, strict=True))
    for name in ("jerk", "trapezoid"):
        figures = by_name[name].figures
        if figures is not None:
            failures = axis_limit_failures(
                figures,
                nc.axis_names,
                v_max=v_top,
                a_max=nc.a_max,
                j_max=nc.j_max if name == "jerk" else None,
            )
            problems += [f"{name}: {text}" for text in failures]
    return {
        "sides": sides,
        "mismatch": acceptance_mismatch(sides),
        "ratio_trapezoid": ratio_trap,
        "ratio_jerk": ratio_jerk,
        "floor": floor,
        "problems": problems,
        "findings": findings,
    }


def _triple(values: tuple[float, ...], scale: float, digits: int) -> str:
    return "/".join(f"{v * scale:.{digits}f}" for v in values)


def print_program(name: str, outcome: dict) -> None:
    print(f"\n{name}")
    print(
        f"  {'side':10s} {'time s':>7s} {'ratio':>6s} {'path um max/rms':>16s} "
        f"{'corner um':>10s} {'n':>3s} {'v_c mm/s':>8s} {'arc um':>7s} "
        f"{'v mm/s X/Y/Z':>17s} {'a m/s2 X/Y/Z':>15s} {'j m/s3 X/Y/Z':>18s}"
    )
    ratios = {"jerk": outcome["ratio_jerk"], "trapezoid": outcome["ratio_trapezoid"]}
    for side in outcome["sides"]:
        if side.error is not None:
            print(f"  {side.name:10s} refused: {side.error}")
            continue
        f = side.figures
        if f is None:
            print(f"  {side.name:10s} ran (no programmed path to measure against)")
            continue
        speeds = [v for v in f.corner_speed_m_s if not math.isnan(v)]
        v_c = sum(speeds) / len(speeds) * MM if speeds else float("nan")
        ratio = ratios.get(side.name)
        print(
            f"  {side.name:10s} {f.program_time_s:7.3f} "
            f"{'' if ratio is None else f'{ratio:.3f}':>6s} "
            f"{f.path_dev_max_m * UM:8.2f}/{f.path_dev_rms_m * UM:<7.2f} "
            f"{f.corner_dev_max_m * UM:10.2f} {len(f.corners):3d} {v_c:8.2f} "
            f"{f.arc_dev_max_m * UM:7.3f} {_triple(f.peak_vel_m_s, MM, 1):>17s} "
            f"{_triple(f.peak_acc_m_s2, 1.0, 2):>15s} {_triple(f.peak_jerk_m_s3, 1.0, 0):>18s}"
        )
    floor = outcome["floor"]
    linuxcnc_side = next((s for s in outcome["sides"] if s.name == "linuxcnc"), None)
    jerk_side = next((s for s in outcome["sides"] if s.name == "jerk"), None)
    if floor is not None and linuxcnc_side is not None and linuxcnc_side.figures is not None:
        ours_over = (
            ""
            if jerk_side is None or jerk_side.figures is None
            else f"; jerk / floor {jerk_side.figures.program_time_s / floor['time_s']:.3f}"
        )
        print(
            f"  {'floor':10s} {floor['time_s']:7.3f} "
            f"{floor['time_s'] / linuxcnc_side.figures.program_time_s:6.3f}  "
            f"(trapezoid + {floor['extra_s']:.3f} s at {floor['near_stops']} near-stops{ours_over})"
        )
    if outcome["mismatch"]:
        print(f"  REPORTED: {outcome['mismatch']}")
    for text in outcome["problems"]:
        print(f"  FAILS: {text}")
    if outcome["findings"]:
        worst = (
            outcome["findings"][0]
            if len(outcome["findings"]) == 1
            else (f"{len(outcome['findings'])} beyond tolerance, e.g. {outcome['findings'][0]}")
        )
        print(f"  LinuxCNC: {worst}")


def _floor_ratio(outcome: dict) -> float | None:
    """The jerk profile's floor over LinuxCNC's time."""
    linuxcnc_side = next(s for s in outcome["sides"] if s.name == "linuxcnc")
    if outcome["floor"] is None or linuxcnc_side.figures is None:
        return None
    return outcome["floor"]["time_s"] / linuxcnc_side.figures.program_time_s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "axis_default.yaml")
    parser.add_argument("-k", dest="only", default="", help="only programs whose name has this")
    parser.add_argument(
        "--linuxcnc-cache",
        type=Path,
        default=None,
        help="directory where LinuxCNC's trajectories are saved and reused (see above)",
    )
    args = parser.parse_args(argv)
    nc, servo = machine_for_config(args.config)
    programs = sorted(CORPUS.glob("*.ngc")) + sorted((CORPUS / "disagree").glob("*.ngc"))
    programs = [p for p in programs if args.only in p.name]
    report: dict[str, dict] = {}
    failed: list[str] = []
    started = time.monotonic()
    machine = peer_machine(Path(tempfile.mkdtemp(prefix="feed_twin-peer-")), nc, servo)
    for program in programs:
        outcome = run_one(program, nc, servo, machine, args.linuxcnc_cache)
        name = str(program.relative_to(CORPUS))
        print_program(name, outcome)
        expected_mismatch = program.parent.name == "disagree"
        if expected_mismatch != (outcome["mismatch"] is not None):
            outcome["problems"].append(
                "one side refuses it" if outcome["mismatch"] else "both sides accept it"
            )
        failed += [f"{name}: {text}" for text in outcome["problems"]]
        report[name] = {
            **{s.name: side_summary(s) for s in outcome["sides"]},
            "ratio_trapezoid": outcome["ratio_trapezoid"],
            "ratio_jerk": outcome["ratio_jerk"],
            "floor": outcome["floor"],
            "ratio_floor": _floor_ratio(outcome),
            "mismatch": outcome["mismatch"],
            "linuxcnc_findings": len(outcome["findings"]),
        }
    trap = [r["ratio_trapezoid"] for r in report.values() if r["ratio_trapezoid"] is not None]
    jerk = [r["ratio_jerk"] for r in report.values() if r["ratio_jerk"] is not None]
    floor = [r["ratio_floor"] for r in report.values() if r["ratio_floor"] is not None]
    print(f"\n{len(programs)} programs in {time.monotonic() - started:.0f} s; ", end="")
    print("requirements met" if not failed else f"{len(failed)} requirements broken")
    summary = {
        "benchmark": "linuxcnc_peer",
        "programs": len(programs),
        "requirements_met": not failed,
        "broken": failed,
        "ratio_trapezoid_min": min(trap, default=None),
        "ratio_trapezoid_max": max(trap, default=None),
        "ratio_jerk_min": min(jerk, default=None),
        "ratio_jerk_max": max(jerk, default=None),
        "ratio_floor_min": min(floor, default=None),
        "ratio_floor_max": max(floor, default=None),
        "per_program": report,
    }
    print(json.dumps(summary))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
