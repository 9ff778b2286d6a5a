"""Rerun dashboard of a machine run: the programmed path against the twin's in XY and XZ,
coloured by contour error, with axes in mm and the colour scale; the contour error (normal to
the path) and the lag (along it) in panels of their own, as the lag would flatten the contour
error on one scale; the axes' following errors; the run's figures as text.

Display units here, once: mm for positions, um for errors. The twin's points are coloured from
green (no error) to red (the run's largest contour error). Each path view's bounds are the
path's with a margin, so neither view crops it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from feed_twin.gcode.geometry import PathSegment
from feed_twin.io.dashboard import APPLICATION_ID, TIMELINE
from feed_twin.machine.nodes import MachineRecord
from feed_twin.machine.simulate import MachineRun

MM = 1e3  # display mm per m
UM = 1e6  # display um per m
ARC_POINTS = 181  # points per programmed arc in the path views
VIEWS = (("XY", 0, 1), ("XZ", 0, 2))  # name, horizontal and vertical axis index


def error_colors(error: np.ndarray) -> np.ndarray:
    """RGB per sample: green at 0, red at the largest error (NaN: grey)."""
    top = float(np.nanmax(error)) if np.any(np.isfinite(error)) else 0.0
    share = np.clip(error / top, 0.0, 1.0) if top > 0.0 else np.zeros_like(error)
    share = np.nan_to_num(share, nan=0.5)
    rgb = np.column_stack((255 * share, 200 * (1.0 - share), np.full_like(share, 40.0)))
    return rgb.astype(np.uint8)


def path_points(segments: tuple[PathSegment, ...]) -> np.ndarray:
    """The programmed path (feed moves and rapids) as one polyline [m], (n, axes)."""
    parts = [
        s.point_at(np.linspace(0.0, 1.0, ARC_POINTS if s.arc is not None else 2)) for s in segments
    ]
    return np.concatenate(parts) if parts else np.zeros((0, 3))


def nice_ticks(lo: float, hi: float, *, count: int = 5) -> np.ndarray:
    """About `count` round tick values (1, 2 or 5 times a power of ten apart) within [lo, hi]."""
    span = max(hi - lo, 1e-9)
    raw = span / count
    base = 10.0 ** np.floor(np.log10(raw))
    step = base * min((m for m in (1.0, 2.0, 5.0, 10.0) if m * base >= raw), default=10.0)
    return np.arange(np.ceil(lo / step), np.floor(hi / step) + 1) * step


@dataclass(frozen=True)
class PathFrame:
    """A path view's extent [mm, display: y up] with a margin for the axes and colour scale."""

    x: tuple[float, float]
    y: tuple[float, float]

    @staticmethod
    def around(points_mm: np.ndarray) -> PathFrame:
        finite = points_mm[np.all(np.isfinite(points_mm), axis=1)]
        lo, hi = (finite.min(axis=0), finite.max(axis=0)) if len(finite) else (-1.0, 1.0)
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        pad = 0.08 * max(float(np.max(hi - lo)), 1.0)
        return PathFrame(x=(lo[0] - pad, hi[0] + pad), y=(lo[1] - pad, hi[1] + pad))

    def bounds(self) -> rrb.VisualBounds2D:
        """The whole frame, ticks and colour scale in view (Rerun's 2D y axis points down)."""
        width, height = self.x[1] - self.x[0], self.y[1] - self.y[0]
        return rrb.VisualBounds2D(
            x_range=(self.x[0] - 0.12 * width, self.x[1] + 0.12 * width),
            y_range=(-self.y[1] - 0.10 * height, -self.y[0] + 0.22 * height),
        )


def _log_frame(rec: rr.RecordingStream, root: str, frame: PathFrame, names: tuple[str, str]):
    """Axis lines with round ticks, labelled in mm (display y = -y: Rerun's y points down)."""
    (x0, x1), (y0, y1) = frame.x, frame.y
    rec.log(f"{root}/axes/frame", rr.LineStrips2D(
        [[(x0, -y1), (x0, -y0), (x1, -y0)]], colors=[[150, 150, 150]], radii=rr.Radius.ui_points(1)
    ), static=True)  # fmt: skip
    longest = max(x1 - x0, y1 - y0)  # one scale for both: a short side gets fewer ticks
    xt = nice_ticks(x0, x1, count=max(2, round(5 * (x1 - x0) / longest)))
    yt = nice_ticks(y0, y1, count=max(2, round(5 * (y1 - y0) / longest)))
    tick = 0.015 * longest
    strips = [[(x, -y0), (x, -y0 + tick)] for x in xt] + [[(x0, -y), (x0 - tick, -y)] for y in yt]
    rec.log(f"{root}/axes/ticks", rr.LineStrips2D(strips, colors=[[150, 150, 150]]), static=True)
    labels = [f"{x:g}" for x in xt] + [f"{y:g}" for y in yt]
    where = [(x, -y0 + 3 * tick) for x in xt] + [(x0 - 4 * tick, -y) for y in yt]
    where += [(x1 + 4 * tick, -y0), (x0, -y1 - 3 * tick)]
    labels += [f"{names[0]} [mm]", f"{names[1]} [mm]"]
    rec.log(f"{root}/axes/labels", rr.Points2D(
        where, labels=labels, show_labels=True, radii=0.0, colors=[[200, 200, 200]]
    ), static=True)  # fmt: skip


def _log_scale(rec: rr.RecordingStream, root: str, frame: PathFrame, top_um: float) -> None:
    """The contour-error colour scale under the path: green 0 um to red at the run's largest."""
    (x0, x1), (y0, y1) = frame.x, frame.y
    steps = 10
    width = (x1 - x0) / steps
    share = np.linspace(0.0, 1.0, steps)
    colors = error_colors(share * max(top_um, 1e-12))
    y = -y0 + 0.14 * (y1 - y0)
    mins = [(x0 + k * width, y) for k in range(steps)]
    rec.log(f"{root}/scale/bar", rr.Boxes2D(
        mins=mins, sizes=[(width, 0.04 * (y1 - y0))] * steps, colors=colors
    ), static=True)  # fmt: skip
    rec.log(f"{root}/scale/labels", rr.Points2D(
        [(x0, y + 0.09 * (y1 - y0)), (x1, y + 0.09 * (y1 - y0))],
        labels=["contour error 0 um", f"{top_um:.3g} um"], show_labels=True, radii=0.0,
        colors=[[200, 200, 200]],
    ), static=True)  # fmt: skip


def _summary_text(run: MachineRun | MachineRecord) -> str:
    normal, lag = UM * run.contour.normal_m, UM * run.contour.lag_m
    rows = [
        "| figure | value |",
        "|---|---|",
        f"| contour error, largest | {np.nanmax(normal):.2f} um |",
        f"| contour error, RMS | {np.sqrt(np.nanmean(normal**2)):.2f} um |",
        f"| lag along the path, largest | {np.nanmax(np.abs(lag)):.2f} um |",
    ]
    rows += [
        f"| {a} following error, largest | {UM * np.nanmax(np.abs(fe)):.2f} um |"
        for a, fe in ((a, run.following_error(a)) for a in run.simulated)
    ]
    return "\n".join(
        ["## Machine run", "", *rows, "",
         "The path views colour the twin's tool point by its contour error (the distance from "
         "the programmed path): green at 0, red at the largest. The lag is the distance along "
         "the path behind the command; it is plotted apart, as it dwarfs the contour error."]
    )  # fmt: skip


AXIS_COLORS = ((31, 119, 230), (255, 127, 14), (44, 190, 44), (160, 60, 220))
PANEL_TITLES = (
    "Path XY [mm]",
    "Path XZ [mm]",
    "Contour error, normal to the path [um]",
    "Lag along the path [um]",
    "Following error per axis [um]",
    "Run",
)
GRID_COLUMNS = 2


def write_machine_dashboard(
    run: MachineRun | MachineRecord, segments: tuple[PathSegment, ...], rrd_path: str | Path
) -> Path:
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID)
    programmed = path_points(segments)
    frames = {}
    for name, i, j in VIEWS:
        points = MM * run.actual[:, [i, j]]
        if len(programmed):
            points = np.concatenate((points, MM * programmed[:, [i, j]]))
        frames[name] = PathFrame.around(points)
    rec.set_sinks(rr.FileSink(str(rrd_path)), default_blueprint=machine_blueprint(frames))
    top_um = float(np.nanmax(run.contour.normal_m)) * UM if len(run.t_s) else 0.0
    colors = error_colors(run.contour.normal_m)
    for name, i, j in VIEWS:
        root = name.lower()
        flip = np.array([1.0, -1.0])  # Rerun's 2D y axis points down
        if len(programmed):
            strip = MM * programmed[:, [i, j]] * flip
            rec.log(f"{root}/programmed", rr.LineStrips2D([strip], colors=[[60, 60, 255]]),
                    static=True)  # fmt: skip
        rec.log(
            f"{root}/twin",
            rr.Points2D(MM * run.actual[:, [i, j]] * flip, colors=colors,
                        radii=rr.Radius.ui_points(2)),
            static=True,
        )  # fmt: skip
        _log_frame(rec, root, frames[name], (name[0], name[1]))
        _log_scale(rec, root, frames[name], top_um)
    t = rr.TimeColumn(TIMELINE, duration=run.t_s)
    styles = {"contour/normal": (220, 40, 40), "lag/lag": (160, 60, 220)}
    columns = {"contour/normal": run.contour.normal_m, "lag/lag": run.contour.lag_m}
    for k, a in enumerate(run.simulated):
        styles[f"axes/{a.lower()}"] = AXIS_COLORS[k % len(AXIS_COLORS)]
        columns[f"axes/{a.lower()}"] = run.following_error(a)
    for path, values in columns.items():
        label = path.rsplit("/", 1)[1]
        rec.log(path, rr.SeriesLines(names=[label.upper() if path.startswith("axes") else label],
                                     colors=[styles[path]], widths=[1.5]), static=True)  # fmt: skip
        rec.send_columns(path, indexes=[t], columns=rr.Scalars.columns(scalars=UM * values))
    rec.log("run", rr.TextDocument(_summary_text(run), media_type="text/markdown"), static=True)
    rec.flush()
    rec.disconnect()
    return rrd_path


def machine_blueprint(frames: dict[str, PathFrame]) -> rrb.Blueprint:
    """Paths above, the contour error and the lag apart below, the axes' errors and the
    run's figures last, in a grid of GRID_COLUMNS."""
    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightBottom, visible=True)
    views: list[rrb.View] = [
        rrb.Spatial2DView(
            name=title, origin=f"/{name.lower()}", visual_bounds=frames[name].bounds()
        )
        for title, (name, _, _) in zip(PANEL_TITLES, VIEWS, strict=False)
    ]
    views += [
        rrb.TimeSeriesView(name=PANEL_TITLES[2], origin="/contour", plot_legend=legend),
        rrb.TimeSeriesView(name=PANEL_TITLES[3], origin="/lag", plot_legend=legend),
        rrb.TimeSeriesView(name=PANEL_TITLES[4], origin="/axes", plot_legend=legend),
        rrb.TextDocumentView(name=PANEL_TITLES[5], origin="/run"),
    ]
    return rrb.Blueprint(rrb.Grid(*views, grid_columns=GRID_COLUMNS), collapse_panels=True)
