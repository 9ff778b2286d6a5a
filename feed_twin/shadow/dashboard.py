"""Rerun dashboard of a shadow twin: machine vs twin, residuals, health, on `sim_time`.

| panel                      | entities (SI input, display unit)                              |
|----------------------------|----------------------------------------------------------------|
| Following error [um]       | /following_error/measured, /following_error/twin [m -> um]     |
| Effort [unit]              | /effort/measured, /effort/twin [N, N m or A]                   |
| FE deviation [um]          | /fe_deviation/sample, /fe_deviation/rolling_rms [m -> um]      |
| Effort deviation [unit]    | /effort_deviation/sample, /effort_deviation/rolling_rms        |
| Health                     | /health text log: every verdict that is not OK                 |

Used live by the twin node (a gRPC sink to a viewer) and offline by the replay (an .rrd file);
blocks of residual rows are sent as columns (one `log` call per scalar costs about 60 us).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from feed_twin.io.dashboard import APPLICATION_ID, TIMELINE
from feed_twin.shadow.health import Verdict
from feed_twin.shadow.twin import ResidualBlock

_LEVELS = {1: "WARN", 2: "ERROR", 3: "WARN"}


def blueprint(effort_unit: str) -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Grid(
            rrb.TimeSeriesView(name="Following error [um]", origin="/following_error"),
            rrb.TimeSeriesView(name=f"Effort [{effort_unit}]", origin="/effort"),
            rrb.TimeSeriesView(name="FE deviation [um]", origin="/fe_deviation"),
            rrb.TimeSeriesView(
                name=f"Effort deviation [{effort_unit}]", origin="/effort_deviation"
            ),
            rrb.TextLogView(name="Health", origin="/health"),
            grid_columns=2,
        ),
        collapse_panels=True,
    )


class ShadowDashboard:
    """Send residual blocks and verdicts to an .rrd file and/or a live viewer."""

    def __init__(
        self,
        *,
        effort_unit: str,
        rrd_path: str | Path | None = None,
        live_url: str | None = None,
        batch: int = 250,
    ) -> None:
        if rrd_path is None and live_url is None:
            raise ValueError("ShadowDashboard needs an rrd_path, a live_url or both")
        self._rec = rr.RecordingStream(f"{APPLICATION_ID}_shadow")
        sinks: list = []
        if rrd_path is not None:
            Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(rrd_path)))
        if live_url is not None:
            sinks.append(rr.GrpcSink(url=live_url))
        self._rec.set_sinks(*sinks, default_blueprint=blueprint(effort_unit))
        self._t0: float | None = None
        self._named: set[str] = set()
        self.batch = batch
        self._buffer: list[ResidualBlock] = []
        self._buffered = 0

    def log_block(self, b: ResidualBlock) -> None:
        """Buffer a block; the buffer is sent when it holds `batch` rows (a live twin hands
        over one row per cycle, and each send costs about 0.1 ms per entity)."""
        if not len(b):
            return
        self._buffer.append(b)
        self._buffered += len(b)
        if self._buffered >= self.batch:
            self.flush()

    def flush(self) -> None:
        if not self._buffer:
            return
        b = ResidualBlock.concat(self._buffer) if len(self._buffer) > 1 else self._buffer[0]
        self._buffer, self._buffered = [], 0
        if self._t0 is None:
            self._t0 = float(b.t_s[0])
        t = b.t_s - self._t0
        series = {
            "/following_error/measured": 1e6 * (b.x_cmd_m - b.x_meas_m),
            "/following_error/twin": 1e6 * (b.x_cmd_m - b.x_twin_m),
            "/effort/measured": b.effort_meas,
            "/effort/twin": b.effort_twin,
            "/fe_deviation/sample": 1e6 * b.fe_dev_m,
            "/fe_deviation/rolling_rms": 1e6 * b.fe_dev_rms_m,
            "/effort_deviation/sample": b.effort_dev,
            "/effort_deviation/rolling_rms": b.effort_dev_rms,
        }
        for entity, values in series.items():
            keep = np.isfinite(values)
            if not keep.any():
                continue
            if entity not in self._named:
                self._rec.log(entity, rr.SeriesLines(names=[entity.rsplit("/", 1)[1]]), static=True)
                self._named.add(entity)
            self._rec.send_columns(
                entity,
                indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])],
                columns=rr.Scalars.columns(scalars=values[keep]),
            )

    def log_verdict(self, v: Verdict) -> None:
        if v.level == 0:
            return
        self.flush()
        self._rec.set_time(TIMELINE, duration=v.t_s - (self._t0 or 0.0))
        self._rec.log("/health", rr.TextLog(f"{v.level_name}: {v.message}", level=_LEVELS[v.level]))

    def close(self) -> None:
        self.flush()
        self._rec.flush()
        self._rec.disconnect()
