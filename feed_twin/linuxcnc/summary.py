"""`feed-twin run PROGRAM --nc linuxcnc --shadow`: its pre-check and its figures.

- Before anything starts, both interpreters read the program: one that only LinuxCNC or only
  feed_twin's G-code interpreter accepts is reported, not run on one side (`sides_disagree`).
- The figures: LinuxCNC's program time and largest following error of the twin's joint (from
  the bridge's `LINUXCNC {json}` report), the twin's largest following error (its residuals in
  the bag), the samples received and lost, the bridge latency servo tick -> published and the
  latency servo tick -> the twin's output back at the bridge, and the servo thread's own
  timing (start lateness histogram and late periods, next to the tick count).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from feed_twin.gcode.config import NcConfig
from feed_twin.io.bag import BagReader
from feed_twin.linuxcnc.machine import HalServo
from feed_twin.linuxcnc.period_timing import PeriodTiming
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.run_report import shown


def sides_disagree(program: Path, config: Path) -> str | None:
    """A one-line report when exactly one of the two interpreters rejects `program`."""
    from feed_twin.gcode import load_nc_config
    from feed_twin.linuxcnc.machine import machine_for_config

    nc, servo = machine_for_config(config)
    return interpreters_disagree(program, nc, servo, ours=load_nc_config(config))


def interpreters_disagree(
    program: Path, nc: NcConfig, servo: HalServo, *, ours: NcConfig | None = None
) -> str | None:
    """`sides_disagree` for LinuxCNC's machine (nc, servo) and feed_twin's NC `ours` (default:
    the same nc)."""
    from feed_twin.gcode import GcodeError, validate_program
    from feed_twin.linuxcnc.check import linuxcnc_rejects

    theirs = linuxcnc_rejects(program, nc, servo)
    try:
        validate_program(program, nc if ours is None else ours)
        ours_said = None
    except GcodeError as exc:
        ours_said = str(exc)
    if theirs is not None and ours_said is None:
        return f"feed_twin's interpreter accepts the program but {theirs}; nothing was started"
    if ours_said is not None and theirs is None:
        return (
            f"LinuxCNC accepts the program but feed_twin's interpreter rejects it: {ours_said}; "
            "nothing was started"
        )
    if theirs is not None:
        return f"{theirs}; feed_twin's interpreter rejects it too: {ours_said}"
    return None


@dataclass(frozen=True, kw_only=True)
class LinuxcncFigures:
    program_time_s: float  # [s] LinuxCNC's, first to last motion of the program
    linuxcnc_following_error_max_m: float  # [m] the twin joint's, over the program
    twin_following_error_max_m: float  # [m] the twin's over the shadowed samples
    samples_received: int  # servo periods the bridge received
    # servo periods of the program that did not reach the bag on every topic: the largest of
    # samples_lost_by_topic (gaps in LinuxCNC's tick count, periods never published, messages
    # the recorder did not write); without the bridge's expected counts, the tick gaps alone
    samples_lost: int
    bridge_latency_p50_ms: float  # [ms] servo tick -> its samples published to the twin
    bridge_latency_p99_ms: float  # [ms]
    twin_output_latency_p50_ms: float  # [ms] servo tick -> the twin's output back at the bridge
    twin_output_latency_p99_ms: float  # [ms]
    startup_s: float  # [s] LinuxCNC start-up to the machine homed
    # the servo thread's start lateness and jitter (None from a bridge that did not report it)
    servo_timing: PeriodTiming | None = None
    bag_counts: dict[str, int] = field(default_factory=dict)  # messages per topic in the bag
    samples_lost_by_topic: dict[str, int] = field(default_factory=dict)  # expected - in the bag
    # [ms] p99 of the bridge latency's parts (ServoBridge.mark_published): servo tick ->
    # LinuxCNC's reader, reader -> the bridge, the bridge -> published
    bridge_latency_parts_p99_ms: dict[str, float | None] = field(default_factory=dict)

    def as_dict(self) -> dict:
        out = asdict(self)
        out["servo_timing"] = None if self.servo_timing is None else self.servo_timing.as_dict()
        return out

    def format(self) -> str:
        return "\n".join(
            [
                f"LinuxCNC program time: {shown(self.program_time_s, 's')}",
                f"max following error:  LinuxCNC "
                f"{shown(self.linuxcnc_following_error_max_m, 'um', scale=1e6)}, twin "
                f"{shown(self.twin_following_error_max_m, 'um', scale=1e6)}",
                f"servo samples:         {self.samples_received} received, "
                f"{self.samples_lost} lost (not in the bag on every topic)",
                *(
                    [
                        "lost per topic:        "
                        + ", ".join(f"{t} {n}" for t, n in self.samples_lost_by_topic.items())
                    ]
                    if any(self.samples_lost_by_topic.values())
                    else []
                ),
                *([self.servo_timing.format()] if self.servo_timing is not None else []),
                f"bridge latency:        p50 {shown(self.bridge_latency_p50_ms, 'ms')}, "
                f"p99 {shown(self.bridge_latency_p99_ms, 'ms')} (servo tick -> published)",
                *(
                    [
                        "  its parts' p99:      "
                        + ", ".join(
                            f"{part.replace('_', ' ')} {shown(ms, 'ms')}"
                            for part, ms in self.bridge_latency_parts_p99_ms.items()
                        )
                    ]
                    if self.bridge_latency_parts_p99_ms
                    else []
                ),
                f"twin output latency:   p50 {shown(self.twin_output_latency_p50_ms, 'ms')}, "
                f"p99 {shown(self.twin_output_latency_p99_ms, 'ms')} "
                "(servo tick -> twin's residual)",
            ]
        )


def linuxcnc_figures(bag: Path, *, twin_namespace: str, report: dict) -> LinuxcncFigures:
    """The figures from the bag and the bridge's report (module docstring)."""
    reader = BagReader(bag)
    residual = node_role("twin").topic(twin_namespace, "residual")
    present = {t.name for t in reader.info.topics if t.message_count > 0}
    twin_fe = math.nan
    if residual in present:
        fe = reader.columns(residual, ("following_error_twin",))["following_error_twin"]
        fe = fe[np.isfinite(fe)]
        twin_fe = float(np.max(np.abs(fe))) if fe.size else math.nan

    def number(key: str) -> float:
        value = report.get(key)
        return math.nan if value is None else float(value)

    bag_counts, lost_by_topic, lost = counts_against_expected(reader, report)

    return LinuxcncFigures(
        program_time_s=number("program_time_s"),
        linuxcnc_following_error_max_m=number("linuxcnc_following_error_max_m"),
        twin_following_error_max_m=twin_fe,
        samples_received=int(report.get("samples_received") or 0),
        samples_lost=lost,
        bridge_latency_p50_ms=number("bridge_latency_p50_ms"),
        bridge_latency_p99_ms=number("bridge_latency_p99_ms"),
        twin_output_latency_p50_ms=number("twin_output_latency_p50_ms"),
        twin_output_latency_p99_ms=number("twin_output_latency_p99_ms"),
        startup_s=number("startup_s"),
        servo_timing=servo_timing_from_report(report),
        bag_counts=bag_counts,
        samples_lost_by_topic=lost_by_topic,
        bridge_latency_parts_p99_ms=dict(report.get("bridge_latency_parts_p99_ms") or {}),
    )


def counts_against_expected(
    reader: BagReader, report: dict
) -> tuple[dict[str, int], dict[str, int], int]:
    """The bag's count of every topic the bridge's report expects (`expected`), the shortfall
    per topic, and the samples lost: the largest shortfall (the bridge's own count of periods
    missing between LinuxCNC and the bridge when the report expects nothing)."""
    counts = {t.name: t.message_count for t in reader.info.topics}
    expected = report.get("expected") or {}
    lost_by_topic = {topic: int(n) - counts.get(topic, 0) for topic, n in expected.items()}
    lost = int(report.get("samples_lost") or 0)
    if lost_by_topic:
        lost = max(0, *lost_by_topic.values())
    return {topic: counts.get(topic, 0) for topic in expected}, lost_by_topic, lost


def servo_timing_from_report(report: dict) -> PeriodTiming | None:
    """The bridge's `servo_*` figures (ServoBridge.report) as a PeriodTiming."""
    names = [f.name for f in fields(PeriodTiming)]
    if any(f"servo_{name}" not in report for name in names):
        return None
    values = {name: report[f"servo_{name}"] for name in names}
    values["histogram"] = tuple(values["histogram"])
    return PeriodTiming(**values)
