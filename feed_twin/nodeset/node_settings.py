"""The settings of the node constructors, one frozen dataclass per node that takes many.

A node's `build` reads them from the `ros:` section (feed_twin.nodeset.config) and its command
line; the node's constructor takes the settings, its core object and the ROS context, so a
new setting is one field here, not one more constructor argument (SimNode took 16).
"""

from __future__ import annotations

from dataclasses import dataclass

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.nodeset.config import Boundary, NodeSetConfig


def _at_least(name: str, value: int, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name} = {value!r}: must be a whole number >= {low}")


def _absolute(name: str, topic: str) -> None:
    if not topic.startswith("/"):
        raise ValueError(f"{name} = {topic!r}: must be an absolute topic")


def _named(name: str, value: str) -> None:
    if not value:
        raise ValueError(f"{name} = {value!r}: must not be empty")


@dataclass(frozen=True, kw_only=True)
class SimSettings:
    """The sim node's run: its axis, pacing, scheduling and outputs."""

    settle_s: float  # [s] simulated after the program's end
    joint_name: str  # JointState name
    axis_label: str  # the AxisCommand/AxisState axis field (upper case)
    realtime: bool = False  # paced by the wall clock
    max_time_s: float | None = None  # [s] simulated at most
    clock_divider: int = 1  # /clock and joint_states every this many exchanges [-]
    exchange_cpu: int = -1  # CPU of the exchange (-1: anywhere) [-]
    realtime_priority: int = 0  # SCHED_FIFO priority in real time (0: normal) [-]
    cpu_latency_us: int = -1  # [us] the CPU's wake-up latency asked for (-1: leave it)
    clock_topic: str = "/clock"  # a machine's axis: its `<namespace>/clock`
    record_batch: int = 0  # exchanges per message to the recorder (0: one message each)

    def __post_init__(self) -> None:
        require_nonnegative("settle_s", self.settle_s)
        _named("joint_name", self.joint_name)
        _named("axis_label", self.axis_label)
        if self.max_time_s is not None:
            require_positive("max_time_s", self.max_time_s)
        _at_least("clock_divider", self.clock_divider, 1)
        _at_least("exchange_cpu", self.exchange_cpu, -1)
        _at_least("realtime_priority", self.realtime_priority, 0)
        _at_least("cpu_latency_us", self.cpu_latency_us, -1)
        _at_least("record_batch", self.record_batch, 0)
        _absolute("clock_topic", self.clock_topic)

    @classmethod
    def of(
        cls, ros: NodeSetConfig, *, realtime: bool, max_time_s: float | None, clock_topic: str
    ) -> SimSettings:
        """From the `ros:` section and the node's command line."""
        return cls(
            settle_s=ros.settle_s,
            joint_name=ros.axis,
            axis_label=ros.axis.upper(),
            realtime=realtime,
            max_time_s=max_time_s,
            clock_divider=ros.clock_divider,
            exchange_cpu=ros.exchange_cpu,
            realtime_priority=ros.realtime_priority,
            cpu_latency_us=ros.cpu_latency_us,
            clock_topic=clock_topic,
            record_batch=ros.record_batch,
        )


@dataclass(frozen=True, kw_only=True)
class ControllerSettings:
    """The controller node's exchange with its drive and its outputs."""

    boundary: Boundary  # the CiA 402 split (feed_twin/nodeset/wire.py)
    exchange_period_s: float  # [s] one DriveCommand each
    settle_s: float  # [s] simulated after the program's end
    axis_label: str  # the axis field of the messages (upper case)
    exchange_cpu: int = -1  # CPU of the exchange (-1: anywhere) [-]
    record_batch: int = 0  # exchanges per message to the recorder (0: one message each)
    command_batch: bool = False  # setpoints arrive packed from the G-code node

    def __post_init__(self) -> None:
        require_positive("exchange_period_s", self.exchange_period_s)
        require_nonnegative("settle_s", self.settle_s)
        _named("axis_label", self.axis_label)
        _at_least("exchange_cpu", self.exchange_cpu, -1)
        _at_least("record_batch", self.record_batch, 0)

    @classmethod
    def of(cls, ros: NodeSetConfig, *, command_batch: bool) -> ControllerSettings:
        """From the `ros:` section and the node's command line."""
        return cls(
            boundary=ros.boundary,
            exchange_period_s=ros.exchange_period_s,
            settle_s=ros.settle_s,
            axis_label=ros.axis.upper(),
            exchange_cpu=ros.exchange_cpu,
            record_batch=ros.record_batch,
            command_batch=command_batch,
        )


@dataclass(frozen=True, kw_only=True)
class StandinSettings:
    """The stand-in machine's pacing, send jitter and clock."""

    period_s: float  # [s] one measured sample each (the NC's interpolation period)
    jitter_s: float  # [s] largest send delay (real time only)
    realtime: bool = True  # paced by the wall clock (a follower in lockstep: False)
    clock_divider: int = 10  # a follower's clock every this many samples [-]
    seed: int = 0  # of the jitter
    # where a follower publishes the machine time (a machine's axis: its `<ns>/clock`, which
    # the G-code node reads with --axis-clock)
    clock_topic: str = "/clock"

    def __post_init__(self) -> None:
        require_positive("period_s", self.period_s)
        require_nonnegative("jitter_s", self.jitter_s)
        _at_least("clock_divider", self.clock_divider, 1)
        _at_least("seed", self.seed, 0)
        _absolute("clock_topic", self.clock_topic)
