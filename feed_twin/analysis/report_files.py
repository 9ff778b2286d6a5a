"""What a diagnosis writes into its directory: report.json, report.md, the PNG plots
(feed_twin.analysis.report) and diagnose.rrd (feed_twin.analysis.dashboard)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from feed_twin.analysis.dashboard import write_rerun
from feed_twin.analysis.report import (
    Diagnosis,
    json_default,
    markdown,
    plot_signature,
    plot_traces,
)


def write_report(d: Diagnosis, out_dir: Path, *, v_m_s: np.ndarray) -> list[Path]:
    """Write report.json, report.md, the PNG plots and diagnose.rrd into out_dir."""
    out_dir.mkdir(parents=True, exist_ok=True)
    plots = ["identification.png"]
    plot_traces(d.before_trace, d.after_trace, out_dir / plots[0], "identification run")
    if d.location is not None:
        plots.append("signature.png")
        plot_signature(d.before_trace, v_m_s, d.location, out_dir / plots[-1])
    if d.validation_traces is not None:
        plots.append("validation.png")
        plot_traces(*d.validation_traces, out_dir / plots[-1], "validation run")
    write_rerun(d, out_dir / "diagnose.rrd")
    (out_dir / "report.json").write_text(json.dumps(d.as_dict(), indent=2, default=json_default))
    (out_dir / "report.md").write_text(markdown(d, plots))
    return [out_dir / "report.json", out_dir / "report.md", out_dir / "diagnose.rrd"] + [
        out_dir / p for p in plots
    ]
