"""The `diagnose` recording (diagnose.rrd): measured, nominal and fitted in one panel per
channel and run, the effects it named as text, laid out by a Rerun blueprint.

| panel (per run: identification, validation)  | series (fixed colours in every panel)       |
|----------------------------------------------|---------------------------------------------|
| Following error [um]                         | measured, nominal, fitted                   |
| Effort [unit]                                | measured, nominal, fitted (when recorded)   |
| Effort residual [unit]                       | nominal, fitted: measured minus model       |
| u_q residual [V]                             | nominal, fitted (when the record has u_q)   |
| Effects (full width, below)                  | the verdict, each effect with its units     |
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from feed_twin.analysis.report import Diagnosis, Trace
from feed_twin.plant.slot_specs import with_unit

TIMELINE = "sim_time"
COLORS = {"measured": (31, 119, 230), "nominal": (255, 127, 14), "fitted": (44, 190, 44)}
ROW_SHARES = (3, 1)  # the channels' grid, the effects text
_EFFORT_UNITS = {"force_cmd_N": "N", "torque_cmd_Nm": "N m"}


@dataclass(frozen=True)
class Channel:
    key: str  # entity path part
    title: str


def channels(trace: Trace) -> list[Channel]:
    """The panels a run's trace fills, in order."""
    unit = _EFFORT_UNITS.get(trace.effort_name or "", "A")
    out = [Channel("following_error", "Following error [um]")]
    if trace.effort_meas is not None and trace.effort_sim is not None:
        out += [
            Channel("effort", f"Effort [{unit}]"),
            Channel("effort_residual", f"Effort residual, measured - model [{unit}]"),
        ]
    if trace.u_q_meas_V is not None and trace.u_q_sim_V is not None:
        out.append(Channel("u_q_residual", "u_q residual, measured - model [V]"))
    return out


def runs(d: Diagnosis) -> list[tuple[str, Trace, Trace]]:
    out = [("identification", d.before_trace, d.after_trace)]
    if d.validation_traces is not None:
        out.append(("validation", *d.validation_traces))
    return out


def axis_range(values: list[np.ndarray]) -> tuple[float, float]:
    """Round limits around every finite value: the plot then has ticks beyond a lone "0"
    however short its panel."""
    finite = np.concatenate([v[np.isfinite(v)] for v in values] or [np.zeros(0)])
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
    lo, hi = min(lo, 0.0), max(hi, 0.0)
    span = max(hi - lo, 1e-12)
    step = 10.0 ** np.floor(np.log10(span / 2.0))
    step *= next(m for m in (1.0, 2.0, 5.0, 10.0) if m * step >= span / 2.0)
    lo, hi = float(np.floor(lo / step) * step), float(np.ceil(hi / step) * step)
    margin = 0.08 * (hi - lo)  # the round limits themselves inside, so their ticks are drawn
    return lo - margin, hi + margin


def blueprint(
    run_names: list[str],
    panels: list[Channel],
    ranges: dict[str, tuple[float, float]] | None = None,
) -> rrb.Blueprint:
    """One column per run, one row per channel (y range `ranges[channel key]` when given);
    the effects below, full width."""
    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightBottom, visible=True)
    views: list[rrb.View] = [
        rrb.TimeSeriesView(
            name=f"{c.title}, {run}",
            origin=f"/{run}/{c.key}",
            plot_legend=legend,
            axis_y=rrb.ScalarAxis(range=ranges[c.key]) if ranges and c.key in ranges else None,
        )
        for c in panels
        for run in run_names
    ]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*views, grid_columns=len(run_names)),
            rrb.TextDocumentView(name="Effects", origin="/effects"),
            row_shares=list(ROW_SHARES),
        ),
        collapse_panels=True,
    )


def effects_text(d: Diagnosis) -> str:
    lines = ["## Effects named", "", f"**Verdict:** {d.verdict}", ""]
    for i, e in enumerate(d.effects, 1):
        params = ", ".join(with_unit(k, v) for k, v in e.parameters.items())
        lines.append(
            f"{i}. **{e.name}** ({e.component}): {params}; explains "
            f"{100 * e.explained_fraction:.1f} % of the remaining residual. {e.evidence}"
        )
    lines += [f"- also significant, not fitted: **{u['name']}**: {u['evidence']}"
              for u in d.named_not_fitted]  # fmt: skip
    return "\n".join(lines)


def _series(before: Trace, after: Trace) -> dict[str, np.ndarray]:
    """Channel/label -> values of one run (display units)."""
    series = {
        "following_error/measured": (before.pos_cmd_m - before.x_meas_m) * 1e6,
        "following_error/nominal": (before.pos_cmd_m - before.x_sim_m) * 1e6,
        "following_error/fitted": (after.pos_cmd_m - after.x_sim_m) * 1e6,
    }
    for label, trace in (("nominal", before), ("fitted", after)):
        if trace.effort_meas is not None and trace.effort_sim is not None:
            series["effort/measured"] = trace.effort_meas
            series[f"effort/{label}"] = trace.effort_sim
            series[f"effort_residual/{label}"] = trace.effort_meas - trace.effort_sim
        if trace.u_q_meas_V is not None and trace.u_q_sim_V is not None:
            series[f"u_q_residual/{label}"] = trace.u_q_meas_V - trace.u_q_sim_V
    return {k: np.asarray(v, dtype=float) for k, v in series.items()}


def write_rerun(d: Diagnosis, path: Path) -> None:
    """Measured and model signals, nominal and fitted, of each run, and the effects named."""
    rec = rr.RecordingStream("feed_twin_diagnose")
    panels = channels(d.before_trace)
    data = {run: (before.t_s, _series(before, after)) for run, before, after in runs(d)}
    ranges = {
        c.key: axis_range([v for _, s in data.values() for k, v in s.items()
                           if k.startswith(f"{c.key}/")])
        for c in panels
    }  # fmt: skip
    rec.set_sinks(rr.FileSink(str(path)), default_blueprint=blueprint(list(data), panels, ranges))
    for run, (t, series) in data.items():
        times = rr.TimeColumn(TIMELINE, duration=t)
        for entity, values in series.items():
            label = entity.rsplit("/", 1)[1]
            rec.log(f"{run}/{entity}", rr.SeriesLines(names=[label], colors=[COLORS[label]],
                                                      widths=[1.5]), static=True)  # fmt: skip
            rec.send_columns(
                f"{run}/{entity}", indexes=[times], columns=rr.Scalars.columns(scalars=values)
            )
    rec.log("effects", rr.TextDocument(effects_text(d), media_type="text/markdown"), static=True)
    rec.flush()
    rec.disconnect()
