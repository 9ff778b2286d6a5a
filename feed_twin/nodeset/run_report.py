"""What every `feed-twin run` reports at its end, the same fields in every mode (no rclpy).

`RunReport` holds the run's outputs (bag, Rerun recording, the twin's column map, logs), the
ROS domain other tools join to see it, its timing (speed, lateness against the wall clock in
real-time mode), the samples it stepped, the foreign messages its guards refused, and the
mode's own figures. `format` writes it for a person: every value with its unit, a missing one
in words ("not paced", "none"), never a raw `nan`, `None` or a 16-digit float. `as_dict` is the
same object for `--json` (one strict JSON line through `json_line`): the keys of earlier
versions stay (`bag`, `rrd`, `timing_lateness_p99_ms`, ...), a missing value is null.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

EXIT_INTERRUPTED = 130  # SIGINT's exit status: the figures cover the run until the stop
_LABEL_WIDTH = 22


def _finite(value: Any) -> float | None:
    """A float of `value`, or None for a missing or non-finite one."""
    if value is None or isinstance(value, bool):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def shown(
    value: Any, unit: str, *, scale: float = 1.0, digits: int = 3, missing: str = "not measured"
) -> str:
    """`value * scale` with `digits` decimals and its unit, or `missing` in words for a value
    the run has not (None, NaN): a figure line never shows a raw `nan` or `None`."""
    number = _finite(value)
    return missing if number is None else f"{number * scale:.{digits}f} {unit}"


@dataclass(frozen=True, kw_only=True)
class RunTiming:
    """How fast the run stepped and, paced by the wall clock, how late (None: not measured)."""

    steps: int | None = None  # exchanges stepped by the clock's node [-]
    sim_time_s: float | None = None  # simulated time [s]
    wall_time_s: float | None = None  # wall time of the stepping [s]
    realtime_factor: float | None = None  # simulated / wall time [-]
    lateness_p50_s: float | None = None  # real time only: start after due time, median [s]
    lateness_p99_s: float | None = None  # [s]
    lateness_max_s: float | None = None  # [s]
    missed_steps: int | None = None  # real time only: steps started over a period late [-]

    @classmethod
    def from_report(cls, report: Mapping[str, Any]) -> RunTiming:
        """From a node's TIMING record (feed_twin.nodeset.pacing.pacing_report, ms for lateness)."""

        def ms(key: str) -> float | None:
            value = _finite(report.get(key))
            return None if value is None else value * 1e-3

        steps, missed = report.get("steps"), report.get("missed_steps")
        return cls(
            steps=int(steps) if steps is not None else None,
            sim_time_s=_finite(report.get("sim_time_s")),
            wall_time_s=_finite(report.get("wall_time_s")),
            realtime_factor=_finite(report.get("realtime_factor")),
            lateness_p50_s=ms("lateness_p50_ms"),
            lateness_p99_s=ms("lateness_p99_ms"),
            lateness_max_s=ms("lateness_max_ms"),
            missed_steps=int(missed) if missed is not None else None,
        )

    def as_dict(self) -> dict[str, float | int | None]:
        """The `timing_*` keys of `--json` (lateness in ms, as the TIMING record has it)."""

        def ms(value: float | None) -> float | None:
            return None if value is None else value * 1e3

        return {
            "timing_steps": self.steps,
            "timing_sim_time_s": self.sim_time_s,
            "timing_wall_time_s": self.wall_time_s,
            "timing_realtime_factor": self.realtime_factor,
            "timing_lateness_p50_ms": ms(self.lateness_p50_s),
            "timing_lateness_p99_ms": ms(self.lateness_p99_s),
            "timing_lateness_max_ms": ms(self.lateness_max_s),
            "timing_missed_steps": self.missed_steps,
        }

    def speed_text(self) -> str:
        if self.sim_time_s is None or self.wall_time_s is None:
            return "not measured"
        factor = "" if self.realtime_factor is None else f"{self.realtime_factor:.3g}x real time, "
        return f"{factor}{self.sim_time_s:.3f} s simulated in {self.wall_time_s:.3f} s wall time"

    def lateness_text(self) -> str:
        late = (self.lateness_p50_s, self.lateness_p99_s, self.lateness_max_s)
        if self.missed_steps is None and all(v is None for v in late):
            return "not paced by the wall clock (as fast as it runs)"
        shown = ", ".join(
            f"{name} {'not measured' if v is None else f'{v * 1e3:.3f} ms'}"
            for name, v in zip(("p50", "p99", "max"), late, strict=True)
        )
        missed = "not counted" if self.missed_steps is None else str(self.missed_steps)
        return f"{shown}; missed steps {missed}"


@dataclass(frozen=True, kw_only=True)
class RunReport:
    """The end of a run, whatever its mode; `figure_lines` are the mode's figures, formatted."""

    mode: str  # e.g. "axis nodes", "axis shadow", "axis LinuxCNC shadow"
    exit_code: int
    reason: str = ""  # why the run ended early or failed ("" for a normal end)
    bag: str | None = None  # the recording's directory (None: none was written)
    rrd: str | None = None  # the Rerun recording
    rrd_per_axis: Mapping[str, str | None] = field(default_factory=lambda: MappingProxyType({}))
    column_map: str | None = None  # the twin's column map of the recorded topics (shadow runs)
    logs: str | None = None  # directory of the nodes' logs
    ros_domain: int | None = None  # ROS_DOMAIN_ID of the run (None: the environment's default)
    uses_ros: bool = True  # False: in-process, no node joined any ROS domain
    samples: int | None = None  # exchanges (node set) or command samples (shadow) [-]
    bag_recovered_messages: int | None = None  # a killed recording was recovered with these
    timing: RunTiming = field(default_factory=RunTiming)
    figures: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    figure_lines: tuple[str, ...] = ()
    # topic -> {"messages": n, "reasons": {reason: n}, "publishers": [...]}: what the nodes
    # dropped as not the run's (feed_twin.nodeset.foreign.ForeignLedger.as_dict)
    foreign_messages: Mapping[str, Mapping[str, Any]] = field(
        default_factory=lambda: MappingProxyType({})
    )
    # node -> its longest time without progress [s] said by a peer: slow, not gone, the run
    # went on (feed_twin.nodeset.liveness)
    slow_nodes: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self) -> None:
        if not self.mode:
            raise ValueError("mode = '': must name the run's mode")
        # frozen all the way down: the mappings cannot be changed through the report
        object.__setattr__(self, "figures", MappingProxyType(dict(self.figures)))
        object.__setattr__(self, "rrd_per_axis", MappingProxyType(dict(self.rrd_per_axis)))
        object.__setattr__(self, "slow_nodes", MappingProxyType(dict(self.slow_nodes)))
        foreign = {t: MappingProxyType(dict(e)) for t, e in self.foreign_messages.items()}
        object.__setattr__(self, "foreign_messages", MappingProxyType(foreign))

    @property
    def interrupted(self) -> bool:
        return self.exit_code == EXIT_INTERRUPTED

    def format(self) -> str:
        """The report for a person: the figures, then the run's lines, each with its unit."""
        status = "ended normally" if self.exit_code == 0 else f"exit code {self.exit_code}"
        if self.interrupted:
            status = "interrupted: the figures cover the run until the stop"
        foreign = "; ".join(
            f"{t}: {e.get('messages', 0)} dropped, from {', '.join(e.get('publishers', ()))}"
            for t, e in sorted(self.foreign_messages.items())
        )
        domain = "the environment's" if self.ros_domain is None else str(self.ros_domain)
        if not self.uses_ros:
            domain = "none (in-process, no ROS)"
        recovered = ""
        if self.bag_recovered_messages is not None:
            recovered = f" (incomplete: {self.bag_recovered_messages} messages recovered)"
        rows = [
            ("run", f"{self.mode}, {status}"),
            ("timing", self.timing.speed_text()),
            ("lateness", self.timing.lateness_text()),
            ("samples", "not counted" if self.samples is None else str(self.samples)),
            ("foreign messages", foreign or "none"),
            ("slow nodes", self._slow_text()),
            ("ROS domain", domain),
            ("bag", (self.bag or "none") + (recovered if self.bag else "")),
            ("rerun", self._rrd_text()),
            ("column map", self.column_map or "none"),
            ("logs", self.logs or "none"),
        ]
        lines = [*self.figure_lines, *(f"{k + ':':<{_LABEL_WIDTH}}{v}" for k, v in rows)]
        return "\n".join(lines)

    def _slow_text(self) -> str:
        slow = ", ".join(f"{n} {s:.2f} s" for n, s in sorted(self.slow_nodes.items()))
        return f"{slow} without progress (not gone: the run went on)" if slow else "none"

    def _rrd_text(self) -> str:
        per_axis = ", ".join(f"{a}: {p or 'none'}" for a, p in self.rrd_per_axis.items())
        return ", ".join(t for t in (self.rrd, per_axis) if t) or "none"

    def as_dict(self) -> dict[str, Any]:
        """The same report for `--json`: the earlier keys, the figures flat, the new fields."""
        base = {
            "mode": self.mode,
            "exit_code": self.exit_code,
            "interrupted": self.interrupted,
            "bag_recovered_messages": self.bag_recovered_messages,
            "reason": self.reason,
            "bag": self.bag,
            "rrd": self.rrd,
            "rrd_per_axis": dict(self.rrd_per_axis),
            "column_map": self.column_map,
            "logs": self.logs,
            "ros_domain": self.ros_domain,
            "samples": self.samples,
            "foreign_messages": {
                t: {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in e.items()}
                for t, e in self.foreign_messages.items()
            },
            "slow_nodes": dict(self.slow_nodes),
        }
        # a figure of the same name (the node set's `samples`) does not hide the report's
        figures = {k: v for k, v in self.figures.items() if k not in base}
        return {**base, **figures, **self.timing.as_dict()}


def mode_name(args: Any, *, machine: bool) -> str:
    """The run's mode in words from `feed-twin run`'s options, the same name in every report."""
    where = "machine" if machine else "axis"
    if getattr(args, "in_process", False):
        how = "in-process"
    elif getattr(args, "single_process", False):
        how = "nodes, one process"
    else:
        how = "nodes"
    if getattr(args, "nc", "feed_twin") == "linuxcnc":
        return f"{where} LinuxCNC shadow"
    return f"{where} {how} shadow" if getattr(args, "shadow", False) else f"{where} {how}"


def ros_domain(environ: Mapping[str, str]) -> int | None:
    """The run's ROS_DOMAIN_ID in `environ` (None: unset, the default domain 0)."""
    domain = environ.get("ROS_DOMAIN_ID", "")
    return int(domain) if domain.isdigit() else None


def early_error_report(mode: str, message: str) -> RunReport:
    """The report of a run refused before anything started: every field, nothing written."""
    return RunReport(mode=mode, exit_code=1, reason=message)


def emit(report: RunReport, *, json_out: bool) -> int:
    """Print the report (and with `json_out` its JSON line last); returns its exit code."""
    print(report.format())
    if json_out:
        print(json_line(report.as_dict()))
    return report.exit_code


def json_line(record: dict) -> str:
    """`record` as one strict JSON line: a figure that has no value (NaN, inf) becomes null.

    json.dumps writes NaN as a bare `NaN`, which strict parsers (jq, JavaScript) reject; a run
    without a current (a LinuxCNC servo, the EMPS bench) has no peak current to report.
    """

    def clean(value):
        if isinstance(value, float) and not math.isfinite(value):
            return None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [clean(v) for v in value]
        return value

    return json.dumps(clean(record), allow_nan=False)
