"""The G-code node: plans a program with the core planner and streams AxisCommand setpoints.

- Program: the ROS parameter `program` (a path; set it at start or later through the standard
  parameter service while idle). Loading validates and plans the whole program first
  (`feed_twin.gcode.plan_program`), so a bad program stops before any motion, with the
  interpreter's `file:line:col: ...` message on `program_state` and in the log.
- Services (std_srvs/Trigger) under the node: `start` (also resumes after a pause), `pause`,
  `stop` (ends the program at the next standstill of the planned path, never mid-move; `pause`
  likewise holds at the next standstill: a feed hold mid-move would need a new deceleration
  profile, which the planner does not make).
- M0 pauses; M1 pauses when the parameter `optional_stop` is true. While paused the NC holds the
  position (setpoints at standstill, as a real control does) and the program time stands still;
  `start` resumes.
- Positions: the plant starts at rest at its own position 0, so the setpoints are the twin
  axis's machine positions minus its start position.
- Timing: setpoints are stamped in simulation time, one per interpolation period, and published
  up to `lookahead` periods ahead of the latest /clock so the controller never waits for them.
  In real time the node runs under SCHED_FIFO one priority below the sim's announced exchange
  priority (feed_twin.nodeset.pacing.setpoint_priority): under normal scheduling on a loaded
  host it waited for a CPU longer than its lead. The nodes it shares a process with run so too
  (a machine's recorder); a process that runs higher already keeps its priority.
- A machine (`--machine-axes`, `--command-axes`; feed_twin.machine.nodes): `--autostart`
  waits until every node of every axis beats, and one node commands
  every NC axis, each on its own `/<machine>/<axis>/command`, and announces `program_state` to
  every axis with nodes. It reads each such axis's clock (`<namespace>/clock`) and publishes
  ahead of the slowest: no axis's controller gets a setpoint more than `lookahead` periods
  ahead of any other axis, which holds all axes together in simulated time. In real time
  (announced by the sims) the wall clock holds them together and it publishes ahead of the
  fastest.
- `--command-batch` (a machine, `ros.command_batch`): what one clock message lets it publish
  for an axis with nodes goes to that axis's controller as one RecordBatch on
  `<namespace>/command_batch` (feed_twin.nodeset.record_batch), with each setpoint's
  AxisCommand bytes as on `command`, instead of a datagram per setpoint. `command` still
  carries every setpoint (the recorder beside this node records it from there, by a function
  call). The batch goes out before a `paused` or `finished` state, so the controller has every
  setpoint before it holds the last one.
- `program_state` (latched std_msgs/String): `loaded ...`, `running`, `paused line N ...`,
  `finished <t_ns>`, `stopped <t_ns>`, `error <message>`.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from feed_twin_msgs.msg import AxisCommand
from feed_twin_msgs.msg import RecordBatch as RecordBatchMsg
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from std_srvs.srv import Trigger

from feed_twin.gcode import GcodeError, NcConfig, SampledTrajectory, load_nc_config, plan_program
from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.pacing import announced_priority, setpoint_priority
from feed_twin.nodeset.record_batch import RecordBatch
from feed_twin.nodeset.topics import GCODE_NODE, AxisTopics
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS, raise_priority
from feed_twin.ros.runtime import EXIT_ERROR, FeedTwinNode, NodeOptions, node_main

AXIS_COMMAND = FlatCodec(msg_types.AXIS_COMMAND)
CLOCK = FlatCodec(msg_types.CLOCK).fixed({})
STANDSTILL_M_S = 1e-9  # |v| below which the planned path is at rest [m/s]


class ProgramStream:
    """The setpoint sequence of one axis with pauses, in integer nanoseconds (no rclpy).

    `next_sample()` returns (t_ns, x, v, a, line) of the next setpoint to publish; while paused
    it returns a standstill sample at the paused position and the program time stands still.
    """

    def __init__(
        self,
        trajectory: SampledTrajectory,
        axis: str,
        *,
        period_ns: int,
        t0_ns: int,
        optional_stop: bool,
    ) -> None:
        # Machine coordinates: the sim node starts the table at the NC start position.
        self.x, self.v, self.a = trajectory.axis(axis)
        self.line = trajectory.line
        self.n = len(trajectory)
        self.period_ns = period_ns
        self.t0_ns = t0_ns
        kinds = {"pause"} | ({"optional_pause"} if optional_stop else set())
        period_s = period_ns / NS_PER_S
        self.pause_at: dict[int, tuple[int, str]] = {}
        for event in trajectory.events:
            if event.kind in kinds:
                # The first sample at or after the event: the path is at rest there.
                k = min(self.n - 1, math.ceil(event.t_s / period_s - 1e-6))
                self.pause_at[k] = (event.line, f"line {event.line} ({event.text})")
        self.k = 0  # index of the next program sample
        self.published = 0  # samples published (program + hold)
        self.paused: str | None = None
        self.paused_line = -1  # the M0/M1 line while paused, else of the last pause
        self.stop_requested = False
        self.pause_requested = False
        self.stopped = False

    @property
    def finished(self) -> bool:
        return self.k >= self.n or self.stopped

    @property
    def next_t_ns(self) -> int:
        return self.t0_ns + self.published * self.period_ns

    def next_sample(self) -> tuple[int, float, float, float, int]:
        t_ns = self.next_t_ns
        self.published += 1
        if self.paused is not None:
            k = max(self.k - 1, 0)
            return t_ns, float(self.x[k]), 0.0, 0.0, self.paused_line
        k = self.k
        self.k += 1
        if k in self.pause_at:
            self.paused_line, self.paused = self.pause_at.pop(k)
        at_rest = abs(self.v[k]) < STANDSTILL_M_S and k > 0
        if self.stop_requested and at_rest:
            self.stopped = True
        elif self.pause_requested and at_rest and self.paused is None:
            self.pause_requested = False
            self.paused_line, self.paused = int(self.line[k]), "by request"
        return t_ns, float(self.x[k]), float(self.v[k]), float(self.a[k]), int(self.line[k])

    @property
    def end_t_ns(self) -> int:
        return self.next_t_ns - self.period_ns


class GcodeNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        nc: NcConfig,
        *,
        lookahead: int,
        program: str = "",
        autostart: bool = False,
        optional_stop: bool = False,
        axis_clocks: bool = False,
        command_batch: bool = False,
        context=None,
    ) -> None:
        super().__init__(GCODE_NODE, options, context=context)
        self.axis_clocks = axis_clocks  # a machine: each sim publishes <namespace>/clock
        self.nc = nc
        self.lookahead = lookahead
        self.period_ns = round(nc.interpolation_period_s * NS_PER_S)
        self.streams: list[ProgramStream] = []  # one per commanded axis, in step
        self.trajectory: SampledTrajectory | None = None
        self.running = False
        self._clock_ns = 0
        self._realtime = False
        served = options.axis_topics()
        commanded = [(nc.twin_axis, self.topics)] + [
            (a.upper(), AxisTopics(machine=options.machine, axis=a))
            for a in (*options.other_axes, *options.command_axes)
        ]
        self._labels = tuple(label for label, _ in commanded)
        self._commands = [
            AXIS_COMMAND.fixed({"axis": label})  # the run's signature fills the frame_id
            for label in self._labels
        ]
        self._pubs = [self.create_publisher(AxisCommand, t.command, DATA_QOS) for _, t in commanded]
        self._command_topics = [t.command for _, t in commanded]
        # (batch, its publisher) per commanded axis; None for an axis without a controller.
        # Sent after each _publish_ahead (`_send_batches`); the batch's exchange count is not
        # used, so its capacity (lookahead: the most one clock message lets it publish) is
        # nominal.
        with_nodes = {t.namespace for t in served.values()}
        self._batches: list[tuple[RecordBatch, Publisher] | None] = [
            (
                RecordBatch((t.command,), lookahead),
                self.create_publisher(RecordBatchMsg, t.command_batch, DATA_QOS),
            )
            if command_batch and t.namespace in with_nodes
            else None
            for _, t in commanded
        ]
        self._state_pubs = [
            self.create_publisher(String, t.program_state, LATCHED_QOS) for t in served.values()
        ]
        if axis_clocks:
            self._clocks = dict.fromkeys(served, 0)
            for prefix, t in served.items():
                self.create_subscription(
                    Clock,
                    f"{t.namespace}/clock",
                    functools.partial(self._on_axis_clock, prefix=prefix),
                    DATA_QOS,
                    raw=True,
                )
        else:
            self.create_subscription(Clock, "/clock", self._on_clock, DATA_QOS, raw=True)
        self.create_service(Trigger, "~/start", self._srv_start)
        self.create_service(Trigger, "~/pause", self._srv_pause)
        self.create_service(Trigger, "~/stop", self._srv_stop)
        self.declare_parameter("optional_stop", optional_stop)
        self.declare_parameter("program", "")
        self.add_on_set_parameters_callback(self._on_parameters)
        self.autostart = autostart
        if program:
            self.set_parameters([Parameter("program", value=program)])
        self.start_heartbeat(when=lambda: self.recorder_listens(self._pubs))
        if axis_clocks:
            # A machine starts once every axis's nodes beat: its sims start on "running", so in
            # real time all axes start together instead of each when its own nodes are up.
            self._start_timer = self.create_timer(0.02, self._start_when_all_up, clock=self.wall)

    def _start_when_all_up(self) -> None:
        if self.autostart and self.trajectory is not None and self.peers_alive():
            self._start_timer.cancel()
            self.start()

    @property
    def stream(self) -> ProgramStream | None:
        """The first axis's stream: every axis pauses, stops and ends with it."""
        return self.streams[0] if self.streams else None

    def _state(self, text: str) -> None:
        for pub in self._state_pubs:
            pub.publish(String(data=self.auth.sign_text(pub.topic_name, text)))
        self.get_logger().info(f"program: {text}")

    def load(self, program: str) -> bool:
        try:
            trajectory = plan_program(Path(program), self.nc)
        except GcodeError as exc:
            self._state(f"error {exc}")
            self.finish(EXIT_ERROR, f"G-code error: {exc}")
            return False
        self.trajectory = trajectory
        duration = len(trajectory) * self.nc.interpolation_period_s
        self._state(f"loaded {program} {len(trajectory)} samples {duration:.3f} s")
        self.get_logger().info(f"loaded {program}: {len(trajectory)} samples, {duration:.3f} s")
        if self.autostart and not self.axis_clocks:
            self.start()
        return True

    def start(self) -> str:
        if self.stream is not None and self.stream.paused is not None:
            for stream in self.streams:
                stream.paused = None
            self._state("running")
            return "resumed"
        if self.trajectory is None:
            return "no program loaded"
        if self.running:
            return "already running"
        self.streams = [
            ProgramStream(
                self.trajectory,
                label,
                period_ns=self.period_ns,
                t0_ns=self._clock_ns,
                optional_stop=bool(self.get_parameter("optional_stop").value),
            )
            for label in self._labels
        ]
        self.running = True
        self._state("running")
        self._publish_ahead()
        return "started"

    def _publish_ahead(self) -> None:
        stream = self.stream
        if stream is None or not self.running:
            return
        horizon = self._clock_ns + self.lookahead * self.period_ns
        was_paused = stream.paused
        outputs = list(
            zip(
                self.streams, self._commands, self._pubs, self._batches, self._command_topics,
                strict=True,
            )
        )  # fmt: skip
        now_ns = time.time_ns()  # the batches' publish time (not read by the controllers)
        sign = self.auth.sign
        while not stream.finished and stream.next_t_ns <= horizon:
            for each, command, pub, batch, topic in outputs:
                t_ns, x, v, a, line = each.next_sample()
                sec, nsec = divmod(t_ns, NS_PER_S)
                data = sign(topic, command.encode((sec, nsec, x, v, a, line)))
                pub.publish(data)
                if batch is not None:
                    batch[0].add(0, data, now_ns)
            if stream.paused is not None and was_paused is None:
                self._send_batches()
                self._state(f"paused {stream.paused}")
                was_paused = stream.paused
        self._send_batches()
        if stream.finished and self.running:
            self.running = False
            word = "stopped" if stream.stopped else "finished"
            self._state(f"{word} {stream.end_t_ns}")

    def _send_batches(self) -> None:
        for batch in self._batches:
            data = batch[0].take() if batch is not None else None
            if batch is not None and data is not None:
                batch[1].publish(data)

    def _on_clock(self, data: bytes) -> None:
        sec, nsec = CLOCK.decode(data)
        self._clock_ns = sec * NS_PER_S + nsec
        self._publish_ahead()

    def _on_axis_clock(self, data: bytes, prefix: str) -> None:
        sec, nsec = CLOCK.decode(data)
        self._clocks[prefix] = sec * NS_PER_S + nsec
        # In lockstep the slowest axis sets the horizon: the others wait for it. In real time
        # every sim paces itself by the wall clock and cannot wait: the fastest sets it (an
        # axis whose sim started later would otherwise miss steps until the others caught up).
        pick = max if self._realtime else min
        self._clock_ns = pick(self._clocks.values())
        self._publish_ahead()

    def on_run_state(self, text: str) -> None:
        # the sims announce real-time pacing on run_state (latched), before their first step
        priority = announced_priority(text)
        if priority is None or self._realtime:
            return
        self._realtime = True
        # the controller waits for the setpoints: they must not wait behind the host's load
        for note in raise_priority(setpoint_priority(priority)):
            self.get_logger().info(f"scheduling: {note}")

    def _on_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for p in params:
            if p.name == "program" and p.value:
                if self.running:
                    return SetParametersResult(
                        successful=False, reason="a program is running; stop it first"
                    )
                if not self.load(str(p.value)):
                    return SetParametersResult(successful=False, reason=self.exit_message)
        return SetParametersResult(successful=True)

    def _srv_start(self, request, response):
        result = self.start()
        response.success = result in ("started", "resumed")
        response.message = result
        return response

    def _srv_pause(self, request, response):
        if self.stream is None or not self.running:
            response.success, response.message = False, "not running"
        else:
            for stream in self.streams:
                stream.pause_requested = True
            response.success, response.message = True, "pausing at the next standstill"
        return response

    def _srv_stop(self, request, response):
        if self.stream is None or not self.running:
            response.success, response.message = False, "not running"
        else:
            for stream in self.streams:
                stream.stop_requested = True
                stream.paused = None
            response.success, response.message = True, "stopping at the next standstill"
        return response


def program_lines(path: str | Path) -> dict[int, str]:
    """Source text per 1-based line number, for the dashboard's G-code log."""
    text = Path(path).read_text(encoding="utf-8", errors="replace")
    return {i + 1: line.rstrip() for i, line in enumerate(text.splitlines())}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--program", default="")
    parser.add_argument("--autostart", action="store_true")
    parser.add_argument("--optional-stop", action="store_true")
    parser.add_argument(
        "--axis-clock",
        action="store_true",
        help="a machine: read every served axis's <namespace>/clock (sim_node --axis-clock) and "
        "start the program (--autostart) once every node of every axis beats",
    )
    parser.add_argument(
        "--command-batch",
        action="store_true",
        help="also send each axis's setpoints packed on <namespace>/command_batch (a machine's "
        "controllers read them there)",
    )


def build(args: argparse.Namespace, ros, options: NodeOptions, context) -> GcodeNode:
    return GcodeNode(
        options,
        load_nc_config(args.config),
        lookahead=ros.lookahead,
        program=args.program,
        autostart=args.autostart,
        optional_stop=args.optional_stop,
        axis_clocks=args.axis_clock,
        command_batch=args.command_batch,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    return node_main(argv, prog="gcode node", configure=configure, build=build)


if __name__ == "__main__":
    sys.exit(main())
