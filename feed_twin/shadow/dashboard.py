"""Rerun dashboard of a shadow twin: machine vs twin, residuals, health, on `sim_time`.

| panel                      | entities (SI input, display unit)                              |
|----------------------------|----------------------------------------------------------------|
| Position [mm]              | /position/{command,measured,twin} [m -> mm]                    |
| Following error [um]       | /following_error/{measured,twin,warning} [m -> um]             |
| Effort [unit]              | /effort/{measured,twin,warning} [N, N m or A]                  |
| Health level               | /health_level/level: 0 OK, 1 WARN, 2 ERROR, 3 STALE            |
| FE deviation [um]          | /fe_deviation/{sample,rolling_rms} [m -> um]                   |
| Effort deviation [unit]    | /effort_deviation/{sample,rolling_rms}                         |
| Health (full width, below) | /health text log: the start and every change of verdict        |

Measured is blue and the twin orange in every panel; a red cross marks each warning on the
plots. A machine that sends no effort (LinuxCNC) gets no effort panels rather than a flat zero:
the layout is chosen at the first block. Used live by the twin node (a gRPC sink to a viewer)
and offline by the replay (an .rrd file); blocks of residual rows are sent as columns (one `log`
call per scalar costs about 60 us).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from feed_twin.io.dashboard import APPLICATION_ID, TIMELINE
from feed_twin.shadow.health import LEVEL_NAMES, Verdict
from feed_twin.shadow.twin import ResidualBlock

_LEVELS = {0: "INFO", 1: "WARN", 2: "ERROR", 3: "WARN"}
MEASURED, TWIN = (31, 119, 230), (255, 127, 14)  # blue and orange in every panel
SAMPLE, RMS, WARNING = (160, 60, 220), (44, 190, 44), (220, 40, 40)
COLORS = {
    "command": RMS,
    "measured": MEASURED,
    "twin": TWIN,
    "sample": SAMPLE,
    "rolling_rms": RMS,
    "level": WARNING,
}
ROW_SHARES = (3, 1)  # plots, health log
LEVEL_TITLE = "Health level (" + ", ".join(f"{k} {n}" for k, n in LEVEL_NAMES.items()) + ")"


def panels(effort_unit: str, *, with_effort: bool) -> list[tuple[str, str]]:
    """(title, origin) of the plot panels, in grid order; the health log follows them."""
    out = [("Position [mm]", "/position"), ("Following error [um]", "/following_error")]
    if with_effort:
        out.append((f"Effort [{effort_unit}]", "/effort"))
    out += [(LEVEL_TITLE, "/health_level"), ("FE deviation [um]", "/fe_deviation")]
    if with_effort:
        out.append((f"Effort deviation [{effort_unit}]", "/effort_deviation"))
    return out


def grid_columns(*, with_effort: bool) -> int:
    return 3 if with_effort else 2


def blueprint(effort_unit: str, *, with_effort: bool = True) -> rrb.Blueprint:
    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightBottom, visible=True)
    views: list[rrb.View] = []
    for title, origin in panels(effort_unit, with_effort=with_effort):
        # the level axis spans every level, so an all-OK run shows 0..3 rather than one "0"
        axis = (
            rrb.ScalarAxis(range=(-0.2, 3.2), zoom_lock=True) if origin == "/health_level" else None
        )
        views.append(rrb.TimeSeriesView(name=title, origin=origin, plot_legend=legend, axis_y=axis))
    columns = rrb.TextLogColumns(
        text_log_columns=[
            rrb.components.TextLogColumn("LogLevel"),
            rrb.components.TextLogColumn("Body"),
            rrb.components.TextLogColumn("EntityPath", visible=False),
        ]
    )
    # the log spans the width below the plots, so a verdict's message is not cut
    health = rrb.TextLogView(name="Health", origin="/health", columns=columns)
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*views, grid_columns=grid_columns(with_effort=with_effort)),
            health,
            row_shares=list(ROW_SHARES),
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
        self._sinks: list = []
        if rrd_path is not None:
            Path(rrd_path).parent.mkdir(parents=True, exist_ok=True)
            self._sinks.append(rr.FileSink(str(rrd_path)))
        if live_url is not None:
            self._sinks.append(rr.GrpcSink(url=live_url))
        self.effort_unit = effort_unit
        self._opened = False
        self.with_effort = True
        self._t0: float | None = None
        self._named: set[str] = set()
        self.batch = batch
        self._buffer: list[ResidualBlock] = []
        self._buffered = 0
        self._level: int | None = None
        self._last = (np.zeros(0), np.zeros(0), np.zeros(0))  # t, FE um, effort: markers

    def _open(self, *, with_effort: bool) -> None:
        """Sinks and layout, once the first block says whether the machine sends effort."""
        if self._opened:
            return
        self._opened = True
        self.with_effort = with_effort
        layout = blueprint(self.effort_unit, with_effort=with_effort)
        self._rec.set_sinks(*self._sinks, default_blueprint=layout)
        self._rec.log(
            "/health_level/level",
            rr.SeriesLines(names=["level"], colors=[WARNING], widths=[2.0]),
            static=True,
        )
        for panel in ("/following_error", "/effort"):
            self._rec.log(
                f"{panel}/warning",
                rr.SeriesPoints(names=["warning"], colors=[WARNING], markers=["Cross"],
                                marker_sizes=[6.0]),
                static=True,
            )  # fmt: skip

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
        self._open(with_effort=bool(np.isfinite(b.effort_meas).any()))
        if self._t0 is None:
            self._t0 = float(b.t_s[0])
            self._rec.set_time(TIMELINE, duration=0.0)
            self._rec.log("/health", rr.TextLog("shadow twin started: OK", level="INFO"))
        t = b.t_s - self._t0
        fe_meas = 1e6 * (b.x_cmd_m - b.x_meas_m)
        series = {
            "/position/command": 1e3 * b.x_cmd_m,
            "/position/measured": 1e3 * b.x_meas_m,
            "/position/twin": 1e3 * b.x_twin_m,
            "/following_error/measured": fe_meas,
            "/following_error/twin": 1e6 * (b.x_cmd_m - b.x_twin_m),
            "/fe_deviation/sample": 1e6 * b.fe_dev_m,
            "/fe_deviation/rolling_rms": 1e6 * b.fe_dev_rms_m,
        }
        if self.with_effort:
            series |= {
                "/effort/measured": b.effort_meas,
                "/effort/twin": b.effort_twin,
                "/effort_deviation/sample": b.effort_dev,
                "/effort_deviation/rolling_rms": b.effort_dev_rms,
            }
        for entity, values in series.items():
            keep = np.isfinite(values)
            if not keep.any():
                continue
            if entity not in self._named:
                label = entity.rsplit("/", 1)[1]
                style = rr.SeriesLines(names=[label], colors=[COLORS[label]], widths=[1.5])
                self._rec.log(entity, style, static=True)
                self._named.add(entity)
            self._rec.send_columns(
                entity,
                indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])],
                columns=rr.Scalars.columns(scalars=values[keep]),
            )
        self._last = (t, fe_meas, b.effort_meas)

    def log_verdict(self, v: Verdict) -> None:
        """The level over time on every verdict; a text row and plot markers on a change of
        verdict and on every warning."""
        self.flush()
        self._open(with_effort=True)
        t = v.t_s - (self._t0 or 0.0)
        self._rec.set_time(TIMELINE, duration=t)
        self._rec.log("/health_level/level", rr.Scalars(float(v.level)))
        if v.level == 0 and self._level in (None, 0):
            self._level = 0
            return
        self._level = v.level
        self._rec.log("/health", rr.TextLog(f"{v.level_name}: {v.message}", level=_LEVELS[v.level]))
        times, fe, effort = self._last
        if v.level == 0 or not len(times):
            return
        self._rec.log("/following_error/warning", rr.Scalars(float(np.interp(t, times, fe))))
        if self.with_effort and np.isfinite(effort).any():
            value = float(np.interp(t, times, np.nan_to_num(effort)))
            self._rec.log("/effort/warning", rr.Scalars(value))

    def close(self) -> None:
        self.flush()
        self._open(with_effort=True)
        self._rec.flush()
        self._rec.disconnect()
