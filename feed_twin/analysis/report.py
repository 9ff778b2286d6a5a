"""What a diagnosis reports: report.md, the JSON layout and the PNG plots (feed_twin.analysis
.report_files writes them with diagnose.rrd into the output directory).

Display units (mm, um) appear only here; every input is SI. The JSON layout is the issue's:
`effects` is a list of `{name, evidence, parameters, explained_fraction}` in the order found,
`before` and `after` hold the metrics on the identification run and `validation` (when a
second run was given) the metrics of the nominal and the final model on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from feed_twin.analysis.compare import Alignment, Metrics  # noqa: E402
from feed_twin.analysis.locate import Location  # noqa: E402
from feed_twin.plant.slot_specs import with_unit


@dataclass(frozen=True, kw_only=True, eq=False)
class Trace:
    """Measured and simulated signals of one run on one time base (SI)."""

    label: str
    t_s: np.ndarray
    pos_cmd_m: np.ndarray
    x_meas_m: np.ndarray
    x_sim_m: np.ndarray
    effort_meas: np.ndarray | None
    effort_sim: np.ndarray | None
    effort_name: str | None  # canonical name, e.g. force_cmd_N
    u_q_meas_V: np.ndarray | None = None  # the current controller's q-voltage, when recorded
    u_q_sim_V: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True)
class FoundEffect:
    name: str
    evidence: str
    parameters: dict[str, float]
    explained_fraction: float  # [1] share of the fit cost this effect removed
    component: str
    # reported parameter -> its 95 % interval (low, high) at the final model (analysis.appraise)
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "evidence": self.evidence,
            "parameters": self.parameters,
            "intervals": {k: list(v) for k, v in self.intervals.items()},
            "explained_fraction": self.explained_fraction,
            "component": self.component,
        }


@dataclass(frozen=True, kw_only=True, eq=False)
class Diagnosis:
    measured: str
    config: str
    model_path: str
    alignment: Alignment
    before: Metrics
    after: Metrics
    before_trace: Trace
    after_trace: Trace
    effects: tuple[FoundEffect, ...]
    verdict: str
    location: Location | None
    ranking: tuple[dict[str, Any], ...] = ()  # last ranking of every candidate, for the record
    validation: dict[str, Any] | None = None
    # significant signatures the workflow could not add to the model: {name, evidence, reason}
    named_not_fitted: tuple[dict[str, str], ...] = ()
    validation_traces: tuple[Trace, Trace] | None = None
    notes: tuple[str, ...] = ()  # warnings of the loader, fit convergence messages
    timings_s: dict[str, float] = field(default_factory=dict)
    # each channel's residual at the final model against its noise (analysis.verdict.Leftover)
    leftover: tuple[dict[str, Any], ...] = ()
    # intervals, correlations, implausible values, drifts (analysis.appraise.Appraisal)
    appraisal: dict[str, Any] = field(default_factory=dict)
    appraisal_lines: tuple[str, ...] = ()
    # the search's cost: parameter sets simulated (in batches) and seconds up to the appraisal
    search: dict[str, float] = field(default_factory=dict)
    # what the record can show (analysis.visibility.Visibility.as_dict, plus the lines said)
    visibility: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "measured": self.measured,
            "config": self.config,
            "model": self.model_path,
            "verdict": self.verdict,
            "alignment": {
                "time_shift_s": self.alignment.time_shift_s,
                "position_offset_m": self.alignment.position_offset_m,
                "correlation": self.alignment.correlation,
            },
            "effects": [e.as_dict() for e in self.effects],
            "named_not_fitted": list(self.named_not_fitted),
            "before": self.before.as_dict(),
            "after": self.after.as_dict(),
            "validation": self.validation,
            "location": None if self.location is None else self.location.as_dict(),
            "ranking": list(self.ranking),
            "leftover": list(self.leftover),
            "appraisal": self.appraisal,
            "search": self.search,
            "notes": list(self.notes),
            "timings_s": self.timings_s,
            "visibility": self.visibility,
        }


def _fmt(value: float | None, scale: float = 1.0, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value * scale:.{digits}g}"


def _metrics_rows(label: str, m: Metrics) -> str:
    return (
        f"| {label} | {_fmt(m.fe_dev_rms_m, 1e6)} | {_fmt(m.fe_dev_max_m, 1e6)} | "
        f"{_fmt(m.pos_rel_err_pct)} | {_fmt(m.effort_rel_err_pct)} | "
        f"{_fmt(m.voltage_q_rms_V)} |"
    )


def markdown(d: Diagnosis, plots: list[str]) -> str:
    lines = [
        "# Discrepancy report",
        "",
        f"- measured: `{d.measured}`",
        f"- nominal model: `{d.config}`",
        f"- augmented, fitted model: `{d.model_path}`",
        f"- alignment: time shift {d.alignment.time_shift_s * 1e3:.3f} ms, position offset "
        f"{d.alignment.position_offset_m * 1e6:.3f} um (correlation {d.alignment.correlation:.4f})",
        "",
        f"**Verdict:** {d.verdict}",
        "",
    ]
    if d.visibility is not None:
        lines += ["## What this record can show", ""]
        lines += [f"- {s}" for s in d.visibility.get("said", [])] + [""]
    lines += ["## Effects found (in the order found)", ""]
    if not d.effects:
        lines.append(d.verdict[:1].upper() + d.verdict[1:] + ".")
    for i, e in enumerate(d.effects, 1):
        params = ", ".join(with_unit(k, v) for k, v in e.parameters.items())
        lines += [
            f"{i}. **{e.name}** ({e.component}), explains "
            f"{100 * e.explained_fraction:.1f} % of the remaining residual",
            f"   - evidence: {e.evidence}",
            f"   - fitted: {params}",
        ]
        if e.intervals:
            lines.append(
                "   - 95 % intervals: "
                + ", ".join(f"{k} {lo:.5g} .. {hi:.5g}" for k, (lo, hi) in e.intervals.items())
            )
    if d.named_not_fitted:
        lines += ["", "Also significant, but not fitted (no way to add it to this model yet):", ""]
        lines += [f"- **{u['name']}**: {u['evidence']}" for u in d.named_not_fitted]
    lines += [
        "",
        "## Before and after",
        "",
        "| model | FE deviation RMS [um] | FE deviation max [um] | position rel. err [%] "
        "| effort rel. err [%] | u_q residual RMS [V] |",
        "|---|---|---|---|---|---|",
        _metrics_rows("nominal", d.before),
        _metrics_rows("augmented", d.after),
    ]
    if d.search:
        lines += [
            "",
            f"Search: {d.search['simulations']:.0f} parameter sets simulated (in batches of the "
            f"engine) in {d.search['seconds']:.2f} s"
            + (
                f", of which the joint selection (analysis.joint) fitted "
                f"{d.search['joint_trials']:.0f} swapped sets with "
                f"{d.search['joint_simulations']:.0f} in {d.search['joint_seconds']:.2f} s."
                if d.search.get("joint_trials")
                else "."
            ),
        ]
    if d.appraisal_lines:
        lines += ["", "## How far to trust the fit", ""] + list(d.appraisal_lines)
    if d.leftover:
        lines += ["", "## What is left (final model against each channel's sample noise)", ""]
        lines += [
            f"- {c['channel']}: RMS {c['rms']:.3g} {c['unit']} = {c['noise_ratio']:.3g} x its "
            f"sample noise; {c['signature']}"
            for c in d.leftover
        ]
    if d.validation is not None:
        lines += [
            "",
            f"## Validation on `{d.validation['measured']}`",
            "",
            "| model | FE deviation RMS [um] | FE deviation max [um] | position rel. err [%] "
            "| effort rel. err [%] | u_q residual RMS [V] |",
            "|---|---|---|---|---|---|",
            _metrics_rows("nominal", Metrics(**d.validation["before"])),
            _metrics_rows("augmented", Metrics(**d.validation["after"])),
        ]
    if d.location is not None:
        lines += ["", "## Where the nominal model disagrees", ""]
        lines += [f"- {s}" for s in d.location.summary()]
    if d.ranking:
        lines += [
            "",
            "## Last ranking of the library (on the final model's residual)",
            "",
            "| effect | explained [%] | p | significant |",
            "|---|---|---|---|",
        ]
        for r in d.ranking:
            lines.append(
                f"| {r['name']} | {100 * r['explained_fraction']:.2f} | {r['p_value']:.2g} | "
                f"{'yes' if r['significant'] else 'no'} |"
            )
    if d.notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in d.notes]
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(lines) + "\n"


def _effort_axis_label(name: str | None) -> str:
    return {"force_cmd_N": "force [N]", "torque_cmd_Nm": "torque [N m]"}.get(
        name or "", "q-current [A]"
    )


def plot_traces(before: Trace, after: Trace, path: Path, title: str) -> None:
    """Measured vs twin (before and after): following error, effort, q-voltage, residuals."""
    t = before.t_s
    rows = 4 if before.effort_meas is not None else 2
    has_u = before.u_q_meas_V is not None and before.u_q_sim_V is not None
    rows += 1 if has_u else 0
    fig, axes = plt.subplots(rows, 1, figsize=(11, 2.6 * rows), sharex=True)
    fe_meas = (before.pos_cmd_m - before.x_meas_m) * 1e6
    ax = axes[0]
    ax.plot(t, fe_meas, lw=0.8, color="k", label="measured")
    ax.plot(t, (before.pos_cmd_m - before.x_sim_m) * 1e6, lw=0.8, label="nominal twin")
    ax.plot(t, (after.pos_cmd_m - after.x_sim_m) * 1e6, lw=0.8, label="augmented twin")
    ax.set_ylabel("following error [um]")
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[1]
    ax.plot(t, (before.x_sim_m - before.x_meas_m) * 1e6, lw=0.8, label="nominal")
    ax.plot(t, (after.x_sim_m - after.x_meas_m) * 1e6, lw=0.8, label="augmented")
    ax.set_ylabel("FE deviation [um]")
    ax.legend(loc="upper right", fontsize=8)
    if before.effort_meas is not None and before.effort_sim is not None:
        label = _effort_axis_label(before.effort_name)
        ax = axes[2]
        ax.plot(t, before.effort_meas, lw=0.6, color="k", label="measured")
        ax.plot(t, before.effort_sim, lw=0.6, label="nominal twin")
        if after.effort_sim is not None:
            ax.plot(t, after.effort_sim, lw=0.6, label="augmented twin")
        ax.set_ylabel(label)
        ax.legend(loc="upper right", fontsize=8)
        ax = axes[3]
        ax.plot(t, before.effort_meas - before.effort_sim, lw=0.6, label="nominal")
        if after.effort_sim is not None:
            ax.plot(t, after.effort_meas - after.effort_sim, lw=0.6, label="augmented")
        ax.set_ylabel(f"residual {label}")
        ax.legend(loc="upper right", fontsize=8)
    if before.u_q_meas_V is not None and before.u_q_sim_V is not None:  # has_u
        ax = axes[-1]
        ax.plot(t, before.u_q_meas_V - before.u_q_sim_V, lw=0.6, label="nominal")
        if after.u_q_meas_V is not None and after.u_q_sim_V is not None:
            ax.plot(t, after.u_q_meas_V - after.u_q_sim_V, lw=0.6, label="augmented")
        ax.set_ylabel("residual u_q [V]")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_signature(trace: Trace, v_m_s: np.ndarray, location: Location, path: Path) -> None:
    """The located signature: residual against velocity, by direction, and over the stroke."""
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    if trace.effort_meas is not None and trace.effort_sim is not None:
        r = trace.effort_meas - trace.effort_sim
        unit = _effort_axis_label(trace.effort_name)
    else:
        r = (trace.x_sim_m - trace.x_meas_m) * 1e6
        unit = "FE deviation [um]"
    step = max(1, len(r) // 5000)
    axes[0].plot(v_m_s[::step] * 1e3, r[::step], ".", ms=1.5, alpha=0.5)
    axes[0].set_xlabel("velocity [mm/s]")
    axes[0].set_ylabel(f"nominal residual, {unit}")
    b = location.by_direction
    axes[1].bar(b.labels, b.mean)
    axes[1].set_ylabel(f"mean residual, {unit}")
    axes[1].set_title("by direction of motion")
    p = location.by_position
    centres = 0.5 * (np.array(p.edges[:-1]) + np.array(p.edges[1:]))
    axes[2].plot(centres * 1e3, p.mean, "o-", label="mean")
    axes[2].plot(centres * 1e3, p.rms, "s--", label="RMS")
    axes[2].set_xlabel("position [mm]")
    axes[2].set_ylabel(f"residual, {unit}")
    axes[2].legend(fontsize=8)
    axes[2].set_title("along the screw")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
