"""A "real machine" for the shadow twin: the stand-in truth model as a ROS 2 node.

The truth (feed_twin.shadow.standin.StandIn: the model with hidden effects, a current-loop lag,
the real sensor quantisation, effort noise; `shadow.standin` of the config) answers each NC
sample with a measured sample and publishes it, stamped with the NC sample's stamp, on
`<ns>/joint_states` (sensor_msgs/JointState, as joint_state_broadcaster publishes it): the
measured position [m] and the drive effort (N, or A for a PMSM model). Two command sources:

- built-in (`feed-twin shadow`): the repeated synthetic program of feed_twin.shadow.standin,
  one sample every `--period` of wall-clock time (t_k = k * period); the node publishes the
  NC setpoints on `<ns>/command` (AxisCommand) itself.
- `--follow` (`feed-twin run PROGRAM --shadow`): the G-code node's AxisCommand stream on
  `<ns>/command`. The node publishes `/clock` (the machine time reached, every
  `ros.clock_divider` samples), which paces the G-code node's lookahead, as the sim node does;
  an axis of a machine (`--axis-clock`, feed_twin.machine.shadow_nodes) publishes it on
  `<ns>/clock`, and the G-code node follows the slowest axis.
  Lockstep (default): a sample is played as soon as its command is there, at most
  `LOCKSTEP_WINDOW` samples ahead of the twin's published state (`<ns>/twin/state`), so a slow
  twin is never flooded and the run is as fast as the twin. `--realtime`: sample k is played at
  wall time start + k * period whatever the twin does, as a machine would; a command that has
  not arrived `COMMAND_GRACE_S` after that instant (a stalled process finds it waiting in the
  middleware) is extrapolated from the last one at its velocity (counted as `late_commands`;
  the command itself is dropped when it comes). The program's
  end (`finished`/`stopped` on program_state) ends the run: `done: program finished` on
  run_state, so every node of the set finishes.

Realistic transport (real time only): each message leaves after a random delay, uniform in
[0, jitter], on top of the scheduler's own jitter (stamps stay on the cycle); one topic's
messages keep their order, as one writer's do. The truth's Coulomb friction is its start value
times the parameter `friction_scale` (default 1.0), which can be set while the node runs
(`ros2 param set /cnc/x/standin friction_scale 1.35`, or the parameter service), or scheduled
(`shadow.standin.friction_steps`, or `--raise-friction-at T --friction-scale S`; machine time
since the first command). Stderr: `PROGRESS <machine time>` lines and, at the end,
`TIMING {json}` (samples, real-time factor; in real time the lateness of the samples and the
samples played more than one period late, `missed_steps`).
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import sys
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import AxisCommand, AxisState
from rcl_interfaces.msg import SetParametersResult
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from feed_twin.analysis.twin import ModelDoc
from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.node_settings import StandinSettings
from feed_twin.nodeset.roles import node_role
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS
from feed_twin.ros.runtime import (
    EXIT_ERROR,
    EXIT_OK,
    PEER_TIMEOUT_S,
    FeedTwinNode,
    NodeOptions,
    start_node,
)
from feed_twin.shadow.bagstreams import encode_joint_state
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.replay import twin_namespace
from feed_twin.shadow.standin import StandIn, program_command

COMMAND = FlatCodec(msg_types.AXIS_COMMAND)
NS = 1_000_000_000
LINGER_S = 1.0  # [s] the node stays after the last sample so that readers receive everything
LOCKSTEP_WINDOW = 100  # samples the stand-in may be ahead of the twin's output in lockstep
BURST = 50  # samples played per spin turn at most (lockstep), so callbacks are served
COMMAND_GRACE_S = 0.02  # [s] past its instant a command still absent counts as missing
SPIN_SLICE_S = 2e-4  # [s] executor turn while a due command may still be in the middleware
PROGRESS_PERIOD_S = 0.5


class StandInNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        settings: StandinSettings,
        *,
        standin: StandIn,
        program: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
        schedule: Sequence[tuple[float, float]] = (),
        context=None,
    ) -> None:
        """`program`: (t, x, v, a) of the built-in program; None follows `<ns>/command`."""
        super().__init__("standin", options, context=context)
        self.standin = standin
        self.period_s = period_s = settings.period_s
        self.period_ns = round(period_s * NS)
        self.follow = program is None
        self.realtime = settings.realtime or not self.follow
        self.jitter_s = settings.jitter_s if self.realtime else 0.0
        self.clock_divider = settings.clock_divider
        clock_topic = settings.clock_topic
        self.k = 0
        self._rng = np.random.default_rng(settings.seed)
        self._schedule = sorted(schedule)
        self._queue: list[tuple[float, int, str, bytes]] = []  # (release, seq, topic, data)
        self._seq = 0
        self._last_release: dict[str, float] = {}
        self._friction = {name: standin.parameter(name) for name in standin.friction_parameters()}
        self._js_pub = self.create_publisher(JointState, self.topics.joint_states, DATA_QOS)
        self._run_pub = self.create_publisher(String, self.topics.run_state, LATCHED_QOS)
        self._cmd_pub: Publisher | None = None  # the stand-in NC's, when it plays a program
        # NC samples still to play: (stamp [ns], x, v, a)
        self._commands: deque[tuple[int, float, float, float]] = deque()
        self._t0_ns: int | None = None
        self._end_ns: int | None = None
        self._last_cmd: tuple[int, float, float, float] | None = None
        self._twin_count = 0
        self.late_commands = 0
        if program is None:  # follow
            self.create_subscription(AxisCommand, self.topics.command, self._on_command, DATA_QOS)
            self.create_subscription(
                String, self.topics.program_state, self._on_program_state, LATCHED_QOS
            )
            if not self.realtime:  # lockstep paces itself by the twin's output
                self.create_subscription(
                    AxisState,
                    node_role("twin").topic(twin_namespace(self.topics.command), "state"),
                    self._on_twin_state,
                    DATA_QOS,
                    raw=True,
                )
            self._clock_pub = self.create_publisher(Clock, clock_topic, DATA_QOS)
            self._clock_msg = Clock()
            self._waiting = False
            self.watch_input(
                self.topics.command,
                msg_types.AXIS_COMMAND,
                armed=lambda: self._waiting and not self.run_ended,
            )
        else:
            t, x, v, a = program
            self._commands.extend(
                (round(float(t[k]) * NS), float(x[k]), float(v[k]), float(a[k]))
                for k in range(len(t))
            )
            self._end_ns = self._commands[-1][0]
            self._cmd_pub = self.create_publisher(AxisCommand, self.topics.command, DATA_QOS)
        self.declare_parameter("friction_scale", 1.0)
        self.add_on_set_parameters_callback(self._on_parameters)
        self.start: float | None = None
        self.wall_end: float | None = None
        self._done_at: float | None = None
        self._progress_at = 0.0
        self.lateness_s: list[float] = []
        self.start_heartbeat(when=lambda: self.recorder_listens((self._js_pub,)))

    def _on_command(self, msg: AxisCommand) -> None:
        stamp = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        self._commands.append((stamp, msg.position, msg.velocity, msg.acceleration))

    def _on_program_state(self, msg: String) -> None:
        word, _, rest = msg.data.partition(" ")
        if word in ("finished", "stopped"):
            self._end_ns = int(rest.split()[0])

    def _on_twin_state(self, data: bytes) -> None:
        self._twin_count += 1

    def _on_parameters(self, params) -> SetParametersResult:
        for p in params:
            if p.name == "friction_scale":
                value = float(p.value)
                if not value > 0.0:
                    return SetParametersResult(
                        successful=False, reason=f"friction_scale = {value!r}: must be > 0"
                    )
                self._scale_friction(value)
        return SetParametersResult(successful=True)

    def _scale_friction(self, scale: float) -> None:
        for name, nominal in self._friction.items():
            self.standin.set_parameter(name, nominal * scale)
        self.get_logger().info(f"truth friction x{scale:g} from t = {self._machine_time():.3f} s")

    def _machine_time(self) -> float:
        """[s] since the first command, of the next sample."""
        return self.k * self.period_s

    def poll(self) -> float | None:
        if self.done:
            return None
        now = time.perf_counter()
        if now - self._progress_at > PROGRESS_PERIOD_S and self.start is not None:
            self._progress_at = now
            print(f"PROGRESS {self._machine_time():.3f}", file=sys.stderr, flush=True)
            # discovery may bring another run's node in at any time, not only before the start
            crowded = self._crowded_topics()
            if crowded:
                self.finish(EXIT_ERROR, crowded)
                return None
        if self.start is None:
            # begin when the set is up and someone listens to the measurement (the twin node)
            ready = self.peers_alive() and self._js_pub.get_subscription_count() > 0
            if not (ready and self._commands):
                return 0.01
            crowded = self._crowded_topics()
            if crowded:
                self.finish(EXIT_ERROR, crowded)
                return None
            self.start = now + (0.05 if self.realtime else 0.0)
            self._t0_ns = self._commands[0][0]
            self.standin.reset(self._commands[0][1])
        if not self._ended():
            wait = self._play_realtime(now) if self.realtime else self._play_lockstep()
        else:
            wait = None
        while self._queue and self._queue[0][0] <= now:
            _, _, topic, data = heapq.heappop(self._queue)
            self._send(topic, data)
        if self._ended() and not self._queue:
            if self._done_at is None:
                self.wall_end = now
                done = self.auth.sign_text(self.topics.run_state, "done: program finished")
                self._run_pub.publish(String(data=done))
                self._done_at = now
            # stay a moment: a writer that leaves at once can take unacknowledged samples along
            if now - self._done_at > LINGER_S:
                self.finish(EXIT_OK, "")
                return None
            return 0.05
        due = [] if wait is None else [wait]
        if self._queue:
            due.append(self._queue[0][0] - time.perf_counter())
        return max(0.0, min(due)) if due else None

    def _crowded_topics(self) -> str:
        """Why the run cannot start: another run's node on the same topics (the same ROS
        domain and machine/axis names) would feed its samples into this one."""
        if not self.follow:
            return ""
        mine = {self.topics.command: 1, self.topics.joint_states: 1}
        lines = [
            f"{topic} has {self.count_publishers(topic)} publishers, not {n}"
            for topic, n in mine.items()
            if self.count_publishers(topic) > n
        ]
        if not lines:
            return ""
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        return (
            "; ".join(lines) + f": another run on ROS domain {domain}? Stop it, or run this one "
            "in another domain (ROS_DOMAIN_ID) or under other ros.machine/ros.axis names"
        )

    def _send(self, topic: str, data: bytes) -> None:
        """Publish with the run's signature (feed_twin.nodeset.auth)."""
        pub = self._publisher(topic)
        pub.publish(self.auth.sign(pub.topic_name, data))

    def _publisher(self, topic: str) -> Publisher:
        if topic != "command":
            return self._js_pub
        if self._cmd_pub is None:
            raise RuntimeError("the stand-in follows an NC: it publishes no command")
        return self._cmd_pub

    def _ended(self) -> bool:
        if self._end_ns is None or self._t0_ns is None:
            return False
        return self._t0_ns + self.k * self.period_ns > self._end_ns

    def _play_realtime(self, now: float) -> float:
        assert self.start is not None and self._t0_ns is not None
        while not self._ended() and now >= self._due():
            t_ns = self._t0_ns + self.k * self.period_ns
            while self._commands and self._commands[0][0] < t_ns:
                self._commands.popleft()  # arrived after its slot was played: too late
            if self._commands and self._commands[0][0] == t_ns:
                command = self._commands.popleft()
            elif self._last_cmd is None or now - self._due() < COMMAND_GRACE_S:
                # after a stall of this process the command may wait in the middleware: let
                # the executor deliver it (a zero timeout would not) before calling it missing
                return SPIN_SLICE_S
            else:
                # a missing setpoint is extrapolated at the last velocity, as a drive does on a
                # lost fieldbus telegram (holding the position would jerk the axis to a stop)
                self.late_commands += 1
                _, x, v, _ = self._last_cmd
                command = (t_ns, x + v * self.period_s, v, 0.0)
            self.lateness_s.append(now - self._due())
            self._sample(command, now)
        return self._due() - time.perf_counter()

    def _due(self) -> float:
        """Wall-clock instant [perf_counter s] of the next sample (real time)."""
        assert self.start is not None
        return self.start + self.k * self.period_s

    def _play_lockstep(self) -> float | None:
        played = 0
        while (
            self._commands
            and not self._ended()
            and self.k - self._twin_count < LOCKSTEP_WINDOW
            and played < BURST
        ):
            self._sample(self._commands.popleft(), time.perf_counter())
            played += 1
        self._waiting = not self._commands and not self._ended()
        return 0.0 if played == BURST else None

    def _sample(self, command: tuple[int, float, float, float], now: float) -> None:
        t_ns, x, v, a = command
        t_rel = self._machine_time()
        while self._schedule and self._schedule[0][0] <= t_rel + 1e-12:
            _, scale = self._schedule.pop(0)
            self.set_parameters([_param("friction_scale", scale)])
        xm, em = self.standin.step(np.array([x]), np.array([v]), np.array([a]))
        sec, nsec = divmod(t_ns, NS)
        joints = encode_joint_state(t_ns, [self.topics.axis], [float(xm[0])], [], [float(em[0])])
        out = [("joints", joints)]
        if self._cmd_pub is not None:
            out.append(
                (
                    "command",
                    COMMAND.encode_map(
                        {
                            "header.stamp.sec": sec,
                            "header.stamp.nanosec": nsec,
                            "axis": self.topics.axis.upper(),
                            "position": x,
                            "velocity": v,
                            "acceleration": a,
                            "line": -1,
                        }
                    ),
                )
            )
        for topic, data in out:
            if self.jitter_s > 0:
                delay = self._rng.uniform(0.0, self.jitter_s)
                # one writer's messages stay in order (as on a fieldbus or one DDS writer)
                release = max(now + delay, self._last_release.get(topic, 0.0))
                self._last_release[topic] = release
                heapq.heappush(self._queue, (release, self._seq, topic, data))
                self._seq += 1
            else:
                self._send(topic, data)
        self._last_cmd = command
        self.k += 1
        if self.follow and self.k % self.clock_divider == 0:
            # the machine time reached: the G-code node publishes its lookahead beyond it
            self._clock_msg.clock.sec, self._clock_msg.clock.nanosec = divmod(
                t_ns + self.period_ns, NS
            )
            self._clock_pub.publish(self._clock_msg)

    def on_run_done(self, text: str) -> None:
        # this node announces the end itself and leaves after LINGER_S (poll)
        if self._done_at is None:
            self.finish(EXIT_OK, "")

    def timing_report(self) -> dict[str, float | int | None]:
        wall = (self.wall_end or time.perf_counter()) - (self.start or time.perf_counter())
        sim_s = self.k * self.period_s
        report: dict[str, float | int | None] = {
            "steps": self.k,
            "sim_time_s": sim_s,
            "wall_time_s": wall,
            "realtime_factor": sim_s / wall if wall > 0 else None,
        }
        if self.realtime:
            late = np.asarray(self.lateness_s) * 1e3
            report.update(
                lateness_p50_ms=float(np.percentile(late, 50)) if late.size else math.nan,
                lateness_p99_ms=float(np.percentile(late, 99)) if late.size else math.nan,
                lateness_max_ms=float(late.max()) if late.size else math.nan,
                missed_steps=int(np.count_nonzero(late > self.period_s * 1e3)),
                late_commands=self.late_commands,
            )
        return report

    def on_shutdown(self, reason: str) -> None:
        report = self.timing_report()
        if self.realtime and self.lateness_s:
            print(
                f"STANDIN samples {self.k}, lateness p50 {report['lateness_p50_ms']:.3f} ms, "
                f"p99 {report['lateness_p99_ms']:.3f} ms, max {report['lateness_max_ms']:.3f} ms",
                file=sys.stderr,
                flush=True,
            )
        print("TIMING " + json.dumps(report), file=sys.stderr, flush=True)


def _param(name: str, value: float):
    from rclpy.parameter import Parameter

    return Parameter(name, Parameter.Type.DOUBLE, float(value))


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="model YAML with shadow:")
    parser.add_argument(
        "--follow",
        action="store_true",
        help="play the G-code node's command stream (the config's ros: and nc: sections)",
    )
    parser.add_argument("--realtime", action="store_true", help="--follow: pace by wall clock")
    parser.add_argument(
        "--axis-clock",
        action="store_true",
        help="--follow: publish the clock as <namespace>/clock (an axis of a machine, "
        "feed_twin.machine.shadow_nodes)",
    )
    parser.add_argument("--duration", type=float, default=60.0, help="[s] of built-in program")
    parser.add_argument("--period", type=float, default=1e-3, help="[s] machine cycle")
    parser.add_argument("--jitter", type=float, help="[s] largest send delay (shadow.standin)")
    parser.add_argument("--raise-friction-at", type=float, help="[s] machine time")
    parser.add_argument("--friction-scale", type=float, default=1.35)
    parser.add_argument("--machine", default="cnc")
    parser.add_argument("--axis", default="x")
    parser.add_argument("--seed", type=int, help="noise and jitter seed (shadow.standin)")
    parser.add_argument("--peers", default="", help="comma-separated roles to watch")
    parser.add_argument("--startup-timeout", type=float, default=60.0, help="[s]")
    parser.add_argument("--input-timeout", type=float, default=10.0, help="[s]")
    parser.add_argument("--peer-timeout", type=float, default=PEER_TIMEOUT_S, help="[s]")


def build(args: argparse.Namespace, context) -> StandInNode:
    from dataclasses import replace

    doc = ModelDoc.load(args.config)
    config = load_shadow_config(args.config).standin
    if args.seed is not None:
        config = replace(config, seed=args.seed)
    jitter = config.jitter_s if args.jitter is None else args.jitter
    if not jitter >= 0.0:
        raise ValueError(f"--jitter {jitter!r}: must be >= 0")

    machine, axis, divider, program = args.machine, args.axis, 10, None
    if args.follow:
        from feed_twin.gcode import load_nc_config
        from feed_twin.nodeset.config import load_node_set_config

        ros = load_node_set_config(args.config)
        nc = load_nc_config(args.config)
        if abs(nc.interpolation_period_s - args.period) > 1e-12:
            raise ValueError(
                f"{args.config}: nc.interpolation_period_s = {nc.interpolation_period_s!r}: "
                f"the stand-in plays one NC sample per machine cycle ({args.period!r} s)"
            )
        machine, axis, divider = ros.machine, ros.axis, ros.clock_divider
    else:
        program = program_command(args.duration, args.period)
    schedule = [(s.at_s, s.scale) for s in config.friction_steps]
    if args.raise_friction_at is not None:
        schedule.append((args.raise_friction_at, args.friction_scale))

    def make() -> StandIn:
        return StandIn.from_config(doc, config, sample_period_s=args.period, x0_m=0.0)

    from feed_twin.ros.launch import stage

    stage("stand-in: compiling its kernels (numba; cached after the first run)")
    make().step(np.zeros(1), np.zeros(1), np.zeros(1))  # compile before the first heartbeat
    stage("stand-in: waiting for its peers")
    standin = make()
    return StandInNode(
        NodeOptions(
            machine=machine,
            axis=axis,
            peers=tuple(p for p in args.peers.split(",") if p),
            startup_timeout_s=args.startup_timeout,
            input_timeout_s=args.input_timeout,
            peer_timeout_s=args.peer_timeout,
        ),
        StandinSettings(
            period_s=args.period,
            jitter_s=jitter,
            realtime=args.realtime,
            clock_divider=divider,
            seed=config.seed,
            clock_topic=f"/{machine}/{axis}/clock" if args.axis_clock else "/clock",
        ),
        standin=standin,
        program=program,
        schedule=schedule,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="standin node", description=__doc__.splitlines()[0] if __doc__ else None
    )
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("standin node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
