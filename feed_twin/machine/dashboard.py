"""Rerun dashboard of a machine run: the programmed path against the twin's in XY and XZ,
coloured by contour error, beside per-axis following-error panels and the contour error.

Display units here, once: mm for positions, um for errors. The twin's points are coloured from
green (no error) to red (the run's largest contour error).
"""

from __future__ import annotations

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


def write_machine_dashboard(
    run: MachineRun | MachineRecord, segments: tuple[PathSegment, ...], rrd_path: str | Path
) -> Path:
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID)
    path_views = [rrb.Spatial2DView(name=f"Path {name} [mm]", origin=f"/{name.lower()}")
                  for name, _, _ in VIEWS]  # fmt: skip
    series = [rrb.TimeSeriesView(name="Contour error [um]", origin="/contour")]
    series += [
        rrb.TimeSeriesView(name=f"{a} following error [um]", origin=f"/axes/{a.lower()}")
        for a in run.simulated
    ]
    rec.set_sinks(
        rr.FileSink(str(rrd_path)),
        default_blueprint=rrb.Blueprint(
            rrb.Horizontal(rrb.Vertical(*path_views), rrb.Vertical(*series)),
            collapse_panels=True,
        ),
    )
    programmed = path_points(segments)
    colors = error_colors(run.contour.normal_m)
    for name, i, j in VIEWS:
        root = name.lower()
        if len(programmed):
            strip = MM * programmed[:, [i, j]]
            rec.log(f"{root}/programmed", rr.LineStrips2D([strip], colors=[[60, 60, 255]]),
                    static=True)  # fmt: skip
        rec.log(
            f"{root}/twin",
            rr.Points2D(MM * run.actual[:, [i, j]], colors=colors, radii=rr.Radius.ui_points(2)),
            static=True,
        )
    t = rr.TimeColumn(TIMELINE, duration=run.t_s)
    columns = {"contour/normal": run.contour.normal_m, "contour/lag": run.contour.lag_m}
    for a in run.simulated:
        columns[f"axes/{a.lower()}/following_error"] = run.following_error(a)
    for path, values in columns.items():
        rec.send_columns(path, indexes=[t], columns=rr.Scalars.columns(scalars=UM * values))
    rec.flush()
    rec.disconnect()
    return rrd_path
