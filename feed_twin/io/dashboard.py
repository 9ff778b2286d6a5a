"""Rerun dashboard of a feed-axis run: a blueprint laid out in code, on the `sim_time` timeline.

Panels (display units are converted here, once, at the edge; inputs are SI):

| panel                 | signals (input name [SI unit])                                   |
|-----------------------|------------------------------------------------------------------|
| Position [mm]         | x_cmd_m, x_m (table) [m]                                         |
| Following error [um]  | following_error_m [m]                                            |
| Velocity [mm/s]       | v_cmd_m_s, v_m_s [m/s]                                           |
| dq currents [A]       | i_q_ref_A, i_q_A, i_d_ref_A, i_d_A [A]                           |
| Phase currents [A]    | i_a_A, i_b_A, i_c_A [A], the last 40 ms before the time cursor   |
| dq voltages [V]       | u_d_V, u_q_V [V]                                                 |
| DC bus [V]            | u_dc_V [V] (its own scale: 560 V would flatten u_d and u_q)      |
| Friction force [N]    | f_friction_N [N]                                                 |
| G-code                | the active program line, as a text log                           |

`Dashboard` writes an `.rrd` file (always, when given a path) and optionally streams live to a
viewer: feed_twin.io.live.LiveViewer serves Rerun's web viewer (127.0.0.1 unless asked), or the
dashboard connects to a viewer the user started (`rerun`, native). Samples are buffered and sent
as columns, because one `log` call per scalar costs about 60 us.
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

TIMELINE = "sim_time"
APPLICATION_ID = "feed_twin"
GCODE_PATH = "gcode"


@dataclass(frozen=True, kw_only=True)
class Series:
    name: str  # input key, SI unit in its suffix
    path: str  # entity path
    label: str  # legend text
    scale: float  # display value = scale * SI value
    color: tuple[int, int, int]


@dataclass(frozen=True, kw_only=True)
class Panel:
    title: str
    origin: str  # entity subtree shown by the panel
    series: tuple[Series, ...]


# Saturated colours on purpose: the headless render test finds the curves by their saturation.
_BLUE, _ORANGE, _GREEN, _RED, _PURPLE = (
    (31, 119, 230),
    (255, 127, 14),
    (44, 190, 44),
    (220, 40, 40),
    (160, 60, 220),
)

# the phase currents turn at the electrical frequency: over a whole run they fill the panel as a
# solid band, so their panel shows a window that ends at the time cursor
PHASE_WINDOW_S = 0.04

PANELS: tuple[Panel, ...] = (
    Panel(
        title="Position [mm]",
        origin="/position",
        series=(
            Series(name="x_cmd_m", path="/position/command", label="command", scale=1e3,
                   color=_BLUE),
            Series(name="x_m", path="/position/table", label="table", scale=1e3, color=_ORANGE),
        ),
    ),
    Panel(
        title="Following error [um]",
        origin="/following_error",
        series=(
            Series(name="following_error_m", path="/following_error/e", label="e = x_cmd - x",
                   scale=1e6, color=_RED),
        ),
    ),
    Panel(
        title="Velocity [mm/s]",
        origin="/velocity",
        series=(
            Series(name="v_cmd_m_s", path="/velocity/command", label="command", scale=1e3,
                   color=_BLUE),
            Series(name="v_m_s", path="/velocity/table", label="table", scale=1e3,
                   color=_ORANGE),
        ),
    ),
    Panel(
        title="dq currents [A]",
        origin="/current_dq",
        series=(
            Series(name="i_q_ref_A", path="/current_dq/i_q_ref", label="i_q ref", scale=1.0,
                   color=_BLUE),
            Series(name="i_q_A", path="/current_dq/i_q", label="i_q", scale=1.0, color=_ORANGE),
            Series(name="i_d_ref_A", path="/current_dq/i_d_ref", label="i_d ref", scale=1.0,
                   color=_PURPLE),
            Series(name="i_d_A", path="/current_dq/i_d", label="i_d", scale=1.0, color=_GREEN),
        ),
    ),
    Panel(
        title=f"Phase currents, last {PHASE_WINDOW_S * 1e3:g} ms [A]",
        origin="/current_phase",
        series=(
            Series(name="i_a_A", path="/current_phase/i_a", label="i_a", scale=1.0, color=_RED),
            Series(name="i_b_A", path="/current_phase/i_b", label="i_b", scale=1.0,
                   color=_GREEN),
            Series(name="i_c_A", path="/current_phase/i_c", label="i_c", scale=1.0, color=_BLUE),
        ),
    ),
    Panel(
        title="dq voltages [V]",
        origin="/voltage",
        series=(
            Series(name="u_d_V", path="/voltage/u_d", label="u_d", scale=1.0, color=_PURPLE),
            Series(name="u_q_V", path="/voltage/u_q", label="u_q", scale=1.0, color=_ORANGE),
        ),
    ),
    Panel(
        title="DC bus [V]",
        origin="/bus",
        series=(
            Series(name="u_dc_V", path="/bus/u_dc", label="u_dc", scale=1.0, color=_BLUE),
        ),
    ),
    Panel(
        title="Friction force [N]",
        origin="/friction",
        series=(
            Series(name="f_friction_N", path="/friction/f", label="friction on table",
                   scale=1.0, color=_GREEN),
        ),
    ),
)  # fmt: skip
SERIES: dict[str, Series] = {s.name: s for p in PANELS for s in p.series}
SIGNALS: tuple[str, ...] = tuple(SERIES)
GRID_COLUMNS = 3


def blueprint() -> rrb.Blueprint:
    """The dashboard layout: a 3-column grid of time-series panels and the G-code log."""
    window = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-PHASE_WINDOW_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    views: list[rrb.View] = [
        rrb.TimeSeriesView(
            name=p.title,
            origin=p.origin,
            plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.RightBottom, visible=True),
            time_ranges=window if p.origin == "/current_phase" else None,
        )
        for p in PANELS
    ]
    views.append(rrb.TextLogView(name="G-code", origin=f"/{GCODE_PATH}"))
    return rrb.Blueprint(
        rrb.Grid(*views, grid_columns=GRID_COLUMNS),
        collapse_panels=True,
    )


def rerun_binary() -> Path:
    """The real viewer binary shipped in rerun-sdk (bin/rerun is a Python wrapper around it)."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("rerun-sdk's rerun_cli package is not installed")
    path = Path(next(iter(spec.submodule_search_locations))) / "rerun"
    if not path.is_file():
        raise FileNotFoundError(f"the rerun viewer binary is missing: {path}")
    return path


class Dashboard:
    """Log a run's signals and G-code lines to an .rrd file and, optionally, a live viewer.

    `append(t, values)` buffers one sample (SI values keyed by `SIGNALS` names; missing keys are
    simply not plotted); the buffer is sent as columns every `batch` samples and at `flush`.
    `log_columns` sends whole arrays at once. `log_gcode_line` adds the text-log entry of the
    line that becomes active at simulation time `t`.
    """

    def __init__(
        self,
        *,
        rrd_path: str | Path | None,
        live_url: str | None = None,
        recording_id: str | None = None,
        batch: int = 500,
    ) -> None:
        if rrd_path is None and live_url is None:
            raise ValueError("Dashboard needs an rrd_path, a live_url or both")
        if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
            raise ValueError(f"batch = {batch!r}: must be a whole number >= 1")
        self.rrd_path = Path(rrd_path) if rrd_path is not None else None
        self._rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id)
        sinks: list = []
        if self.rrd_path is not None:
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.rrd_path)))
        if live_url is not None:
            sinks.append(rr.GrpcSink(url=live_url))
        self._rec.set_sinks(*sinks, default_blueprint=blueprint())
        for s in SERIES.values():
            self._rec.log(
                s.path, rr.SeriesLines(names=[s.label], colors=[s.color], widths=[2.0]),
                static=True,
            )  # fmt: skip
        self._batch = batch
        self._t: list[float] = []
        self._rows: dict[str, list[float]] = {name: [] for name in SIGNALS}
        self._closed = False

    def append(self, t_s: float, values: Mapping[str, float]) -> None:
        unknown = set(values) - set(SERIES)
        if unknown:
            raise KeyError(
                f"unknown dashboard signal(s) {', '.join(sorted(unknown))}; "
                f"known: {', '.join(SIGNALS)}"
            )
        self._t.append(t_s)
        for name, column in self._rows.items():
            column.append(values.get(name, math.nan))
        if len(self._t) >= self._batch:
            self._send_buffer()

    def log_columns(
        self, t_s: Sequence[float] | np.ndarray, columns: Mapping[str, Sequence[float] | np.ndarray]
    ) -> None:
        t = np.asarray(t_s, dtype=float)
        for name, values in columns.items():
            if name not in SERIES:
                raise KeyError(f"unknown dashboard signal {name!r}; known: {', '.join(SIGNALS)}")
            v = np.asarray(values, dtype=float)
            if v.shape != t.shape:
                raise ValueError(
                    f"signal {name!r} has {v.shape[0] if v.ndim else 0} samples, "
                    f"the time column {t.shape[0]}"
                )
            keep = np.isfinite(v)
            if not keep.any():
                continue
            s = SERIES[name]
            self._rec.send_columns(
                s.path,
                indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])],
                columns=rr.Scalars.columns(scalars=s.scale * v[keep]),
            )

    def log_gcode_line(self, t_s: float, line: int, text: str) -> None:
        self._rec.set_time(TIMELINE, duration=t_s)
        self._rec.log(GCODE_PATH, rr.TextLog(f"N{line}: {text}", level="INFO"))

    def flush(self) -> None:
        self._send_buffer()
        self._rec.flush()

    def close(self) -> None:
        if self._closed:
            return
        self._send_buffer()
        self._rec.flush()
        self._rec.disconnect()
        self._closed = True

    def __enter__(self) -> Dashboard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _send_buffer(self) -> None:
        if not self._t:
            return
        self.log_columns(self._t, self._rows)
        self._t = []
        self._rows = {name: [] for name in SIGNALS}
