"""A run's figures and its Rerun dashboard, computed from the recorded bag (no rclpy).

Everything is read back through `feed_twin.io.bag.BagReader` and placed on the simulation-time
axis by the messages' header stamps, so the summary and the dashboard describe what was
recorded, whichever process produced it.

Figures:
- cycle_time_s: first to last NC setpoint that belongs to a program line (line >= 1);
- following_error_max_m / _rms_m: |x_setpoint - x_table| of AxisState over the cycle;
- current_peak_A: the largest phase-current amplitude sqrt(i_d^2 + i_q^2) (amplitude-invariant
  frame: the peak of the phase currents);
- velocity_peak_m_s: the largest |table velocity|.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from feed_twin.io import msg_types
from feed_twin.io.bag import BagReader
from feed_twin.io.dashboard import Dashboard
from feed_twin.nodeset.run_report import json_line as json_line  # its home before
from feed_twin.nodeset.run_report import shown
from feed_twin.nodeset.topics import AxisTopics

NO_CURRENT = "none (no current recorded)"


@dataclass(frozen=True, kw_only=True)
class RunSummary:
    cycle_time_s: float
    following_error_max_m: float
    following_error_rms_m: float
    current_peak_A: float
    velocity_peak_m_s: float
    sim_time_s: float
    samples: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def format(self) -> str:
        peak_current = shown(self.current_peak_A, "A", digits=2, missing=NO_CURRENT)
        return "\n".join(
            [
                f"cycle time:            {self.cycle_time_s:.3f} s",
                f"following error max:   {self.following_error_max_m * 1e6:.2f} um",
                f"following error RMS:   {self.following_error_rms_m * 1e6:.2f} um",
                f"peak current:          {peak_current}",
                f"peak velocity:         {self.velocity_peak_m_s * 1e3:.2f} mm/s"
                f" ({self.velocity_peak_m_s * 60.0:.2f} m/min)",
                f"simulated time:        {self.sim_time_s:.3f} s ({self.samples} exchanges)",
            ]
        )


STATE_FIELDS = (
    "header.stamp",
    "position_setpoint",
    "table_position",
    "table_velocity",
    "following_error",
    "i_d",
    "i_q",
    "u_d",
    "u_q",
    "u_dc",
    "friction_force",
)


def read_run(
    bag: str | Path, topics: AxisTopics, *, token: str | None = None
) -> dict[str, dict[str, np.ndarray]]:
    """The columns the summary and dashboard need, per topic (empty dict for absent topics).

    With `token` (the run's, feed_twin.nodeset.guard), commands that do not carry it in
    header.frame_id are left out: the bag records a topic's every publisher, and a foreign
    one's messages, refused by the run, are no part of its figures."""
    reader = BagReader(bag)
    present = {t.name for t in reader.info.topics if t.message_count > 0}
    signed = ("header.frame_id",) if token else ()
    wanted = {
        topics.state: STATE_FIELDS,
        topics.command: ("header.stamp", "position", "velocity", "line", *signed),
        topics.feedback: ("header.stamp", "i_a", "i_b", "i_c"),
        topics.drive_command: ("header.stamp", "i_q", "i_d", *signed),
    }
    run = {
        name: reader.columns(name, fields) if name in present else {}
        for name, fields in wanted.items()
    }
    for name in (topics.command, topics.drive_command):
        columns = run[name]
        if token and columns:
            own = columns.pop("header.frame_id") == token
            run[name] = {field: values[own] for field, values in columns.items()}
    return run


def summarise(run: dict[str, dict[str, np.ndarray]], topics: AxisTopics) -> RunSummary:
    state = run[topics.state]
    command = run[topics.command]
    if not state:
        raise ValueError(f"the bag has no {topics.state} messages: nothing was simulated")
    t = state["header.stamp"]
    if command:
        in_program = command["line"] >= 1
        tc = command["header.stamp"][in_program]
        start, end = (float(tc[0]), float(tc[-1])) if tc.size else (0.0, 0.0)
    else:
        start, end = float(t[0]), float(t[-1])
    window = (t >= start) & (t <= end) if end > start else np.ones_like(t, dtype=bool)
    e = state["following_error"][window]
    amplitude = np.hypot(state["i_d"], state["i_q"])
    return RunSummary(
        cycle_time_s=end - start,
        following_error_max_m=float(np.max(np.abs(e))) if e.size else 0.0,
        following_error_rms_m=float(np.sqrt(np.mean(e * e))) if e.size else 0.0,
        current_peak_A=float(np.nanmax(amplitude)) if amplitude.size else 0.0,
        velocity_peak_m_s=float(np.max(np.abs(state["table_velocity"]))),
        sim_time_s=float(t[-1] - t[0]),
        samples=int(t.size),
    )


def write_dashboard(
    run: dict[str, dict[str, np.ndarray]],
    topics: AxisTopics,
    rrd_path: Path,
    *,
    program_lines: dict[int, str] | None = None,
) -> Path:
    """The Rerun recording of a run (dashboard blueprint included)."""
    with Dashboard(rrd_path=rrd_path) as dash:
        state = run[topics.state]
        if state:
            dash.log_columns(
                state["header.stamp"],
                {
                    "x_m": state["table_position"],
                    "following_error_m": state["following_error"],
                    "v_m_s": state["table_velocity"],
                    "i_q_A": state["i_q"],
                    "i_d_A": state["i_d"],
                    "u_d_V": state["u_d"],
                    "u_q_V": state["u_q"],
                    "u_dc_V": state["u_dc"],
                    "f_friction_N": state["friction_force"],
                },
            )
        command = run[topics.command]
        if command:
            dash.log_columns(
                command["header.stamp"],
                {"x_cmd_m": command["position"], "v_cmd_m_s": command["velocity"]},
            )
            lines = command["line"].astype(int)
            changes = np.flatnonzero(np.diff(lines, prepend=-2))
            for k in changes:
                line = int(lines[k])
                if line >= 1:
                    text = (program_lines or {}).get(line, "")
                    dash.log_gcode_line(float(command["header.stamp"][k]), line, text)
        feedback = run[topics.feedback]
        if feedback:
            dash.log_columns(
                feedback["header.stamp"],
                {"i_a_A": feedback["i_a"], "i_b_A": feedback["i_b"], "i_c_A": feedback["i_c"]},
            )
        drive = run[topics.drive_command]
        if drive:
            dash.log_columns(
                drive["header.stamp"], {"i_q_ref_A": drive["i_q"], "i_d_ref_A": drive["i_d"]}
            )
    return rrd_path


class LiveFeed:
    """Decimated live view of the raw per-exchange messages on a Rerun viewer (no rclpy).

    The recorder hands it the CDR bytes it stores; every `decimation`-th message of each topic
    is decoded (`cdr.FlatCodec`) and appended to a `Dashboard` that streams to `live_url`.
    """

    def __init__(
        self,
        topics: AxisTopics,
        live_url: str,
        *,
        decimation: int = 10,
        recording_id: str | None = None,
    ) -> None:
        from feed_twin.io.cdr import FlatCodec

        if decimation < 1:
            raise ValueError(f"decimation = {decimation!r}: must be >= 1")
        self.dashboard = Dashboard(
            rrd_path=None, live_url=live_url, recording_id=recording_id, batch=50
        )
        self.decimation = decimation
        self._count: dict[str, int] = {}
        self._codecs = {
            topics.state: FlatCodec(msg_types.AXIS_STATE),
            topics.command: FlatCodec(msg_types.AXIS_COMMAND),
            topics.feedback: FlatCodec(msg_types.AXIS_FEEDBACK),
            topics.drive_command: FlatCodec(msg_types.DRIVE_COMMAND),
        }
        self._topics = topics
        self._line = -2

    @property
    def fed_topics(self) -> frozenset[str]:
        """The topics it shows."""
        return frozenset(self._codecs)

    def wants(self, topic: str) -> bool:
        return topic in self._codecs

    def feed(self, topic: str, data: bytes) -> None:
        n = self._count.get(topic, 0)
        self._count[topic] = n + 1
        if n % self.decimation:
            return
        m = self._codecs[topic].decode_map(data)
        t = m["header.stamp.sec"] + m["header.stamp.nanosec"] * 1e-9
        topics = self._topics
        if topic == topics.state:
            values = {
                "x_m": m["table_position"],
                "following_error_m": m["following_error"],
                "v_m_s": m["table_velocity"],
                "i_q_A": m["i_q"],
                "i_d_A": m["i_d"],
                "u_d_V": m["u_d"],
                "u_q_V": m["u_q"],
                "u_dc_V": m["u_dc"],
                "f_friction_N": m["friction_force"],
            }
        elif topic == topics.command:
            values = {"x_cmd_m": m["position"], "v_cmd_m_s": m["velocity"]}
            if m["line"] != self._line and m["line"] >= 1:
                self.dashboard.log_gcode_line(t, m["line"], "")
            self._line = m["line"]
        elif topic == topics.feedback:
            values = {"i_a_A": m["i_a"], "i_b_A": m["i_b"], "i_c_A": m["i_c"]}
        else:
            values = {"i_q_ref_A": m["i_q"], "i_d_ref_A": m["i_d"]}
        self.dashboard.append(t, values)

    def close(self) -> None:
        self.dashboard.close()


class LiveFeeds:
    """The live view of every axis a recorder serves: a `LiveFeed` per axis, one axis alone
    as before, a machine's axes each as a recording of its own on the viewer (named by the
    run and the axis's namespace: the axes' dashboards have the same panels)."""

    def __init__(self, topics: Sequence[AxisTopics], live_url: str, *, decimation: int = 10):
        if not topics:
            raise ValueError("LiveFeeds needs the topics of at least one axis")
        run = uuid.uuid4().hex[:12]
        self.feeds = {
            t.namespace: LiveFeed(
                t,
                live_url,
                decimation=decimation,
                recording_id=None if len(topics) == 1 else f"{run}{t.namespace.replace('/', '-')}",
            )
            for t in topics
        }
        self._by_topic = {topic: f for f in self.feeds.values() for topic in f.fed_topics}

    def wants(self, topic: str) -> bool:
        return topic in self._by_topic

    def feed(self, topic: str, data: bytes) -> None:
        self._by_topic[topic].feed(topic, data)

    def close(self) -> None:
        for feed in self.feeds.values():
            feed.close()
