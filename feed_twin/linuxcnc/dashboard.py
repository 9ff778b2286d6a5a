"""Rerun dashboard of a LinuxCNC run (`feed-twin run PROGRAM --nc linuxcnc --shadow`), from the
servo samples the bridge recorded (ServoSample on `<ns>/linuxcnc/servo`), beside the shadow
twin's own dashboard (feed_twin.shadow.dashboard).

| panel                                  | series (display unit)                             |
|----------------------------------------|---------------------------------------------------|
| Servo samples, joint J [mm]            | position command and feedback of the twin's joint |
| LinuxCNC following error [um]          | every joint's f-error                             |
| PID output [mm/s]                      | every joint's servo output (velocity command)     |
| Servo period deviation [us]            | period start minus the nominal: thread latency    |
| Run (full width, below)                | the run's figures: time, errors, samples, latency |
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from feed_twin.linuxcnc.servo_cdr import ServoSampleLayout

TIMELINE = "sim_time"
JOINT_COLORS = ((31, 119, 230), (255, 127, 14), (44, 190, 44))
COMMAND, FEEDBACK, JITTER = (44, 190, 44), (31, 119, 230), (220, 40, 40)
GRID_COLUMNS = 2
ROW_SHARES = (3, 1)  # plots, the run's figures


@dataclass(frozen=True, kw_only=True)
class ServoTrace:
    """The recorded servo periods (SI), joints in `joints` order."""

    t_s: np.ndarray  # (n,) stamp [s]
    tick_time_s: np.ndarray  # (n,) CLOCK_MONOTONIC period start [s]
    joints: tuple[str, ...]
    position_command_m: np.ndarray  # (n, joints)
    position_feedback_m: np.ndarray
    following_error_m: np.ndarray
    servo_output_m_s: np.ndarray


def read_servo_trace(
    bag: Path, topic: str, joints: tuple[str, ...] = ("X", "Y", "Z")
) -> ServoTrace:
    """The ServoSample columns of `topic` in the bag (read at byte offsets when every sample
    has one layout, as the bridge's have: feed_twin.linuxcnc.servo_cdr)."""
    from feed_twin.io.bag import BagReader
    from feed_twin.io.bag.raw import raw_messages

    fields = ("position_command", "position_feedback", "following_error", "servo_output")
    names = ["header.stamp", "tick_time"] + [
        f"{f}[{j}]" for f in fields for j in range(len(joints))
    ]
    reader = BagReader(bag)
    reader.topic(topic)  # BagError naming the bag's topics when it has no such topic
    raw = raw_messages(reader.info.mcap_path, {topic})[topic]
    cols = None
    if raw.table is not None and len(raw.table):
        table = raw.table[np.argsort(raw.log_time_ns, kind="stable")]
        try:
            read = ServoSampleLayout.from_message(table[0].tobytes()).read(table)
        except ValueError:
            read = {}
        if all(name in read or name == "header.stamp" for name in names):
            stamp = read["header.stamp.sec"].astype(float) + read["header.stamp.nanosec"] * 1e-9
            cols = {"header.stamp": stamp, **read}
    if cols is None:
        cols = reader.columns(topic, names)
    per_joint = {
        f: np.column_stack([cols[f"{f}[{j}]"] for j in range(len(joints))]) for f in fields
    }
    return ServoTrace(
        t_s=cols["header.stamp"], tick_time_s=cols["tick_time"], joints=joints,
        position_command_m=per_joint["position_command"],
        position_feedback_m=per_joint["position_feedback"],
        following_error_m=per_joint["following_error"], servo_output_m_s=per_joint["servo_output"],
    )  # fmt: skip


def panel_titles(joint: str) -> list[str]:
    return [
        f"Servo samples, joint {joint} [mm]",
        "LinuxCNC following error [um]",
        "PID output [mm/s]",
        "Servo period deviation from nominal [us]",
    ]


def blueprint(joint: str) -> rrb.Blueprint:
    legend = rrb.PlotLegend(corner=rrb.Corner2D.RightBottom, visible=True)
    origins = ("/servo", "/f_error", "/pid_output", "/period")
    views = [
        rrb.TimeSeriesView(name=title, origin=origin, plot_legend=legend)
        for title, origin in zip(panel_titles(joint), origins, strict=True)
    ]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Grid(*views, grid_columns=GRID_COLUMNS),
            rrb.TextDocumentView(name="Run", origin="/run"),
            row_shares=list(ROW_SHARES),
        ),
        collapse_panels=True,
    )


def write_linuxcnc_dashboard(
    trace: ServoTrace, joint: str, period_s: float, figures: str, rrd_path: Path
) -> Path:
    """The .rrd of a LinuxCNC run: `joint` is the twin's, `figures` the run's summary text."""
    rec = rr.RecordingStream("feed_twin_linuxcnc")
    rec.set_sinks(rr.FileSink(str(rrd_path)), default_blueprint=blueprint(joint))
    j = trace.joints.index(joint)
    series: dict[str, tuple[np.ndarray, tuple[int, int, int]]] = {
        "servo/command": (1e3 * trace.position_command_m[:, j], COMMAND),
        "servo/feedback": (1e3 * trace.position_feedback_m[:, j], FEEDBACK),
    }
    for k, name in enumerate(trace.joints):
        color = JOINT_COLORS[k % len(JOINT_COLORS)]
        series[f"f_error/{name}"] = (1e6 * trace.following_error_m[:, k], color)
        series[f"pid_output/{name}"] = (1e3 * trace.servo_output_m_s[:, k], color)
    ticks = trace.tick_time_s - trace.tick_time_s[0] if len(trace.t_s) else trace.tick_time_s
    nominal = np.arange(len(ticks)) * period_s
    series["period/deviation"] = (1e6 * (ticks - nominal - np.median(ticks - nominal)), JITTER)
    times = rr.TimeColumn(TIMELINE, duration=trace.t_s)
    for entity, (values, color) in series.items():
        label = entity.rsplit("/", 1)[1]
        rec.log(entity, rr.SeriesLines(names=[label], colors=[color], widths=[1.5]), static=True)
        rec.send_columns(entity, indexes=[times], columns=rr.Scalars.columns(scalars=values))
    text = "## LinuxCNC run\n\n```\n" + figures + "\n```"
    rec.log("run", rr.TextDocument(text, media_type="text/markdown"), static=True)
    rec.flush()
    rec.disconnect()
    return rrd_path
