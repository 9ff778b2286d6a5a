"""A "real machine" for the shadow twin: the stand-in truth model, paced by the wall clock.

Plays the repeated synthetic program (feed_twin.shadow.standin) as the machine's NC would, one
sample every `--period` of wall-clock time, runs the truth model on it and publishes, stamped
with the machine's cycle time (t_k = k * period):

- `<ns>/command` (AxisCommand): the NC setpoint (position, velocity, acceleration);
- `<ns>/joint_states` (sensor_msgs/JointState, as joint_state_broadcaster publishes it): the
  measured position [m] and the drive effort (N, or A for a PMSM model).

Realistic transport: each message leaves after a random delay, uniform in [0, `--jitter`],
on top of the scheduler's own jitter (stamps stay on the cycle); one topic's messages keep
their order, as one writer's do. The truth's Coulomb friction is
the nominal one times the parameter `friction_scale` (default 1.0), which can be set while the
node runs (`ros2 param set /cnc/x/standin friction_scale 1.35`, or the parameter service), or
scheduled with `--raise-friction-at T --friction-scale S`. At the end it publishes
`done: program finished` on run_state, so the twin node finishes too.
"""

from __future__ import annotations

import argparse
import heapq
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from feed_twin_msgs.msg import AxisCommand
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from feed_twin.analysis.synthetic import Unmodelled
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.cdr import FlatCodec
from feed_twin.ros.runtime import (
    DATA_QOS,
    EXIT_OK,
    LATCHED_QOS,
    FeedTwinNode,
    NodeOptions,
    start_node,
)
from feed_twin.shadow.bagstreams import encode_joint_state
from feed_twin.shadow.standin import StandIn, program_command

COMMAND = FlatCodec("feed_twin_msgs/msg/AxisCommand")
NS = 1_000_000_000
LINGER_S = 1.0  # [s] the node stays after the last sample so that readers receive everything


class StandInNode(FeedTwinNode):
    def __init__(
        self,
        options: NodeOptions,
        *,
        standin: StandIn,
        duration_s: float,
        period_s: float,
        jitter_s: float,
        schedule: Sequence[tuple[float, float]] = (),
        seed: int = 0,
        context=None,
    ) -> None:
        super().__init__("standin", options, context=context)
        self.standin = standin
        self.period_s = period_s
        self.jitter_s = jitter_s
        self.t, self.x, self.v, self.a = program_command(duration_s, period_s)
        self.k = 0
        self._rng = np.random.default_rng(seed)
        self._schedule = sorted(schedule)
        self._queue: list[tuple[float, int, str, bytes]] = []  # (release, seq, topic, data)
        self._seq = 0
        self._last_release: dict[str, float] = {}
        self._friction = {name: standin.parameter(name) for name in standin.friction_parameters()}
        self._cmd_pub = self.create_publisher(AxisCommand, self.topics.command, DATA_QOS)
        self._js_pub = self.create_publisher(JointState, self.topics.joint_states, DATA_QOS)
        self._run_pub = self.create_publisher(String, self.topics.run_state, LATCHED_QOS)
        self.declare_parameter("friction_scale", 1.0)
        self.add_on_set_parameters_callback(self._on_parameters)
        self.start: float | None = None
        self._done_at: float | None = None
        self.lateness_s: list[float] = []
        self.start_heartbeat()

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
        self.get_logger().info(f"truth friction x{scale:g} from t = {self.k * self.period_s:.3f} s")

    def poll(self) -> float | None:
        if self.done:
            return None
        now = time.perf_counter()
        if self.start is None:
            # wait until someone listens to the measurement (the twin node), then start
            if self._js_pub.get_subscription_count() == 0:
                return 0.01
            self.start = now + 0.05
        n = len(self.t)
        while self.k < n and now >= self.start + self.k * self.period_s:
            self._sample(now)
        while self._queue and self._queue[0][0] <= now:
            _, _, topic, data = heapq.heappop(self._queue)
            (self._cmd_pub if topic == "command" else self._js_pub).publish(data)
        if self.k >= n and not self._queue:
            if self._done_at is None:
                self._run_pub.publish(String(data="done: program finished"))
                self._done_at = now
            # stay a moment: a writer that leaves at once can take unacknowledged samples along
            if now - self._done_at > LINGER_S:
                self.finish(EXIT_OK, "")
                return None
            return 0.05
        due = [self.start + self.k * self.period_s] if self.k < n else []
        if self._queue:
            due.append(self._queue[0][0])
        return max(0.0, min(due) - time.perf_counter())

    def _sample(self, now: float) -> None:
        k = self.k
        t_k = k * self.period_s
        while self._schedule and self._schedule[0][0] <= t_k:
            _, scale = self._schedule.pop(0)
            self.set_parameters([_param("friction_scale", scale)])
        self.lateness_s.append(now - (self.start + t_k))
        sl = slice(k, k + 1)
        xm, em = self.standin.step(self.x[sl], self.v[sl], self.a[sl])
        stamp = round(t_k * NS)
        sec, nsec = divmod(stamp, NS)
        command = COMMAND.encode_map(
            {
                "header.stamp.sec": sec,
                "header.stamp.nanosec": nsec,
                "axis": self.topics.axis.upper(),
                "position": float(self.x[k]),
                "velocity": float(self.v[k]),
                "acceleration": float(self.a[k]),
                "line": -1,
            }
        )
        joints = encode_joint_state(stamp, [self.topics.axis], [float(xm[0])], [], [float(em[0])])
        for topic, data in (("command", command), ("joints", joints)):
            delay = self._rng.uniform(0.0, self.jitter_s) if self.jitter_s > 0 else 0.0
            # one writer's messages stay in order (as on a fieldbus or one DDS writer)
            release = max(now + delay, self._last_release.get(topic, 0.0))
            self._last_release[topic] = release
            heapq.heappush(self._queue, (release, self._seq, topic, data))
            self._seq += 1
        self.k += 1

    def on_shutdown(self, reason: str) -> None:
        late = np.asarray(self.lateness_s) * 1e3
        if late.size:
            print(
                f"STANDIN samples {self.k}, lateness p50 {np.percentile(late, 50):.3f} ms, "
                f"p99 {np.percentile(late, 99):.3f} ms, max {late.max():.3f} ms",
                file=sys.stderr,
                flush=True,
            )


def _param(name: str, value: float):
    from rclpy.parameter import Parameter

    return Parameter(name, Parameter.Type.DOUBLE, float(value))


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, type=Path, help="nominal model YAML")
    parser.add_argument("--duration", type=float, default=60.0, help="[s] of program to play")
    parser.add_argument("--period", type=float, default=1e-3, help="[s] machine cycle")
    parser.add_argument("--jitter", type=float, default=2e-4, help="[s] largest send delay")
    parser.add_argument("--raise-friction-at", type=float, help="[s] machine time")
    parser.add_argument("--friction-scale", type=float, default=1.35)
    parser.add_argument("--machine", default="cnc")
    parser.add_argument("--axis", default="x")
    parser.add_argument("--seed", type=int, default=0)


def build(args: argparse.Namespace, context) -> StandInNode:
    doc = ModelDoc.load(args.config)

    def make() -> StandIn:
        return StandIn(
            doc, hidden={}, unmodelled=Unmodelled(seed=args.seed), sample_period_s=args.period,
            x0_m=0.0,
        )  # fmt: skip

    make().step(np.zeros(1), np.zeros(1), np.zeros(1))  # compile before the first heartbeat
    standin = make()
    schedule = []
    if args.raise_friction_at is not None:
        schedule.append((args.raise_friction_at, args.friction_scale))
    return StandInNode(
        NodeOptions(machine=args.machine, axis=args.axis, peers=()),
        standin=standin,
        duration_s=args.duration,
        period_s=args.period,
        jitter_s=args.jitter,
        schedule=schedule,
        seed=args.seed,
        context=context,
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="standin node", description=__doc__.splitlines()[0])
    configure(parser)
    args = parser.parse_args(argv)
    return start_node("standin node", lambda context: build(args, context))


if __name__ == "__main__":
    sys.exit(main())
