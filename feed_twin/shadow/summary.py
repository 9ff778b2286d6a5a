"""The figures of a shadowed run (`feed-twin run PROGRAM --shadow`), from its recorded bag.

The machine (the stand-in, or a real axis) is known only by what it published, and the twin by
its own topics, so everything comes from the bag (feed_twin.io.bag.BagReader, no rclpy):

- the run figures of the node set (feed_twin.nodeset.summary.RunSummary), here of the machine:
  cycle_time_s over the NC setpoints that belong to a program line, following error
  x_setpoint - x_measured over that cycle (TwinResidual `following_error_measured`), the peak
  of |measured effort| when it is a current [A] (NaN otherwise), the peak |commanded velocity|;
- the shadow figures: RMS and max |following-error deviation| [m] and |effort deviation|
  [effort unit] over every paired sample, the count of WARN/ERROR health verdicts and the last
  non-OK one's message, and the twin's lag p99 [ms] (its `SHADOW {json}` report, wall clock).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from feed_twin.io.bag import BagReader
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.summary import RunSummary
from feed_twin.shadow.health import ERROR, WARN

RESIDUAL_FIELDS = (
    "header.stamp",
    "following_error_measured",
    "following_error_deviation",
    "effort_measured",
    "effort_deviation",
)


@dataclass(frozen=True, kw_only=True)
class ShadowFigures:
    samples: int  # paired samples
    fe_dev_rms_m: float  # [m]
    fe_dev_max_m: float  # [m]
    effort_dev_rms: float  # [effort unit]
    effort_dev_max: float  # [effort unit]
    effort_unit: str
    warnings: int  # WARN and ERROR verdicts
    last_warning: str  # message of the last WARN/ERROR verdict, "" if none
    lag_p99_ms: float  # [ms] wall clock, NaN when the twin reported none
    first_warning_s: float = math.nan  # [s] stamp of the first WARN/ERROR verdict
    # the `feed-twin diagnose` command that names the effect on this bag ("" without a warning
    # or without the config and column map to give it)
    diagnose: str = ""

    def as_dict(self) -> dict[str, float | int | str]:
        return {f"shadow_{k}": v for k, v in asdict(self).items()}

    def format(self) -> str:
        lines = [
            f"shadowed samples:      {self.samples}",
            f"FE deviation RMS/max:  {self.fe_dev_rms_m * 1e6:.3f} / "
            f"{self.fe_dev_max_m * 1e6:.3f} um",
            f"effort deviation:      {self.effort_dev_rms:.4g} / {self.effort_dev_max:.4g} "
            f"{self.effort_unit} (RMS/max)",
            f"health warnings:       {self.warnings}",
            f"twin lag p99:          {self.lag_p99_ms:.3f} ms",
        ]
        if self.last_warning:
            lines.append(f"last warning:          {self.last_warning}")
        if self.diagnose:
            lines.append(f"name the effect:       {self.diagnose}")
        return "\n".join(lines)


def diagnose_command(
    bag: str | Path, *, config: str | Path, column_map: str | Path, start_s: float, end_s: float
) -> str:
    """The `feed-twin diagnose` line for the part of `bag` after the first warning: the
    workflow then sees the changed machine alone, and names what changed."""
    return (
        f"feed-twin diagnose {bag} --config {config} --map {column_map} "
        f"--segment {start_s:.3f}:{end_s:.3f} --out {bag}_diagnosis"
    )


def _rms(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a * a))) if a.size else math.nan


def _max_abs(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.max(np.abs(a))) if a.size else math.nan


def summarise_shadow(
    bag: str | Path,
    *,
    command_topic: str,
    twin_namespace: str,
    effort_unit: str,
    lag_p99_ms: float = math.nan,
    config: str | Path | None = None,
    column_map: str | Path | None = None,
) -> tuple[RunSummary, ShadowFigures]:
    """The run and shadow figures of a recorded shadow run (module docstring); with the run's
    `config` and `column_map`, the diagnose command for a warning."""
    reader = BagReader(bag)
    present = {t.name for t in reader.info.topics if t.message_count > 0}
    residual_topic = node_role("twin").topic(twin_namespace, "residual")
    if residual_topic not in present:
        raise ValueError(f"the bag has no {residual_topic} messages: the twin shadowed nothing")
    r = reader.columns(residual_topic, RESIDUAL_FIELDS)
    t = r["header.stamp"]
    if command_topic in present:
        c = reader.columns(command_topic, ("header.stamp", "velocity", "line"))
        tc = c["header.stamp"][c["line"] >= 1]
        start, end = (float(tc[0]), float(tc[-1])) if tc.size else (float(t[0]), float(t[-1]))
        v_peak = float(np.max(np.abs(c["velocity"]))) if c["velocity"].size else 0.0
    else:
        start, end, v_peak = float(t[0]), float(t[-1]), math.nan
    window = (t >= start) & (t <= end) if end > start else np.ones_like(t, dtype=bool)
    e = r["following_error_measured"][window]
    effort = r["effort_measured"]
    run = RunSummary(
        cycle_time_s=end - start,
        following_error_max_m=_max_abs(e),
        following_error_rms_m=_rms(e),
        current_peak_A=_max_abs(effort) if effort_unit == "A" else math.nan,
        velocity_peak_m_s=v_peak,
        sim_time_s=float(t[-1] - t[0]),
        samples=int(t.size),
    )
    health_topic = node_role("twin").topic(twin_namespace, "health")
    warnings, last, first_s = 0, "", math.nan
    if health_topic in present:
        h = reader.columns(health_topic, ("header.stamp", "level", "message"))
        flagged = np.isin(h["level"], (WARN, ERROR))
        warnings = int(np.count_nonzero(flagged))
        if warnings:
            last = str(h["message"][np.flatnonzero(flagged)[-1]])
            first_s = float(h["header.stamp"][np.flatnonzero(flagged)[0]])
    command = ""
    if warnings and config is not None and column_map is not None:
        command = diagnose_command(
            bag, config=config, column_map=column_map, start_s=first_s, end_s=float(t[-1])
        )
    figures = ShadowFigures(
        samples=int(t.size),
        fe_dev_rms_m=_rms(r["following_error_deviation"]),
        fe_dev_max_m=_max_abs(r["following_error_deviation"]),
        effort_dev_rms=_rms(r["effort_deviation"]),
        effort_dev_max=_max_abs(r["effort_deviation"]),
        effort_unit=effort_unit,
        warnings=warnings,
        last_warning=last,
        lag_p99_ms=lag_p99_ms,
        first_warning_s=first_s,
        diagnose=command,
    )
    return run, figures
