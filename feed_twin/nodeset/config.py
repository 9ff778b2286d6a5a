"""The `ros:` section of an axis config: names, exchange rate, controller/drive split, signals."""

from __future__ import annotations

import dataclasses
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from feed_twin.core.config import from_mapping, load_yaml
from feed_twin.core.validate import require_positive
from feed_twin.nodeset.protection import ProtectionConfig
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.plant.assembly import PlantModel

Boundary = Literal["torque", "velocity", "position", "voltage"]
RecorderHost = Literal["auto", "sim", "own"]
RECORDER_HOSTS: tuple[RecorderHost, ...] = ("auto", "sim", "own")


@dataclass(frozen=True, kw_only=True)
class StateSignals:
    """Engine signal names behind the AxisState fields ("" where the plant has no such signal).

    None (the default) takes the signal from the plant (`resolve`): the component that declares
    the field among its STATE_OUTPUTS (feed_twin.plant.component), whatever its instance name.
    The table is the body named `table` (the axis files' convention). A `ros.signals` entry
    names a signal explicitly; a leading '-' negates it (sign conventions differ).
    """

    table_position: str | None = "table.s"
    table_velocity: str | None = "table.v"
    motor_angle: str | None = None
    motor_velocity: str | None = None
    i_d: str | None = None
    i_q: str | None = None
    u_d: str | None = None
    u_q: str | None = None
    u_dc: str | None = None
    i_dc: str | None = None
    torque_em: str | None = None
    friction_force: str | None = None
    screw_force: str | None = None

    def names(self) -> tuple[str, ...]:
        """The engine signals to record (signs stripped; unresolved fields left out)."""
        return tuple(v.lstrip("-") for v in vars(self).values() if v)

    def resolve(self, plant: PlantModel, available: Collection[str]) -> StateSignals:
        """Every field given: those left None from the components' STATE_OUTPUTS, "" where no
        component declares the field or its signal is not among `available` (the engine's)."""
        found: dict[str, list[str]] = {}
        for name, component in plant.components.items():
            for field_name, output in component.STATE_OUTPUTS.items():
                sign = "-" if output.startswith("-") else ""
                signal = f"{name}.{output.lstrip('-')}"
                if signal in available:
                    found.setdefault(field_name, []).append(sign + signal)
        chosen: dict[str, str] = {}
        for field_name, value in vars(self).items():
            if value is not None:
                continue
            candidates = found.get(field_name, [])
            if len(candidates) > 1:
                raise ValueError(
                    f"ros.signals.{field_name}: {', '.join(candidates)} all stand for it; "
                    "name one in the ros.signals section"
                )
            chosen[field_name] = candidates[0] if candidates else ""
        return dataclasses.replace(self, **chosen)


@dataclass(frozen=True, kw_only=True)
class NodeLoopGains:
    """Gains of the loops the controller node runs at the exchange period (None: derived).

    A velocity loop tuned for 8 kHz inside a drive is unstable at a 1 kHz exchange with one
    period of transport delay; without explicit values `controller_node_config` re-tunes it
    by the symmetric optimum for the node's delays (feed_twin.control.tuning).
    """

    Kv_1_s: float | None = None  # position gain [1/s]
    velocity_Kp: float | None = None  # [effort unit per m/s], load side
    velocity_Ti_s: float | None = None  # [s]
    # at the torque boundary, compare the feedback with the NC's position and velocity as late
    # as the feed-forward shows in it (feed_twin/nodeset/reference_delay.py) [-]
    symmetrize_feed_forward: bool = True

    def __post_init__(self) -> None:
        for name in ("Kv_1_s", "velocity_Kp", "velocity_Ti_s"):
            value = getattr(self, name)
            if value is not None:
                require_positive(name, value)


@dataclass(frozen=True, kw_only=True)
class NodeSetConfig:
    """The `ros:` section of an axis config: names, exchange rate and controller/drive split."""

    machine: str = "cnc"  # first namespace level
    axis: str = "x"  # second namespace level
    exchange_period_s: float = 1.0e-3  # controller <-> drive message period [s]
    boundary: Boundary = "torque"  # CiA 402 split, see feed_twin/nodeset/wire.py
    settle_s: float = 0.2  # simulated time after the program's end [s]
    lookahead: int = 50  # NC setpoints published ahead of the simulation clock [-]
    clock_divider: int = 10  # /clock and joint_states every this many exchanges [-]
    # Scheduling of the two lockstep partners (sim and controller node), where the OS allows it:
    exchange_cpu: int = -1  # CPU both run on (-1: anywhere) [-]
    realtime_priority: int = 0  # SCHED_FIFO priority of both in real-time mode (0: normal) [-]
    # PM QoS CPU wake-up latency the sim process requests for the run (-1: none) [us]
    cpu_latency_us: int = -1
    # "sim": the recorder runs in the sim node's process (no socket between them, see
    # feed_twin/ros/host.py); "own": a process of its own; "auto": with the sim in lockstep,
    # its own in real time (there the sim must not wait while the recorder writes its bag)
    recorder_host: RecorderHost = "auto"
    # nice value of LinuxCNC's bridge and the twin beside it (`--nc linuxcnc`): a larger share
    # of a busy host's CPUs (feed_twin/ros/dds.py); 0: leave; below 0 needs CAP_SYS_NICE [-]
    linuxcnc_nice: int = -10
    # Exchanges per message to the recorder (feed_twin/nodeset/record_batch.py): the sim's
    # feedback, state and joint states and the controller's DriveCommand reach the recorder
    # packed, one message per this many exchanges, instead of one datagram each; 0: each on
    # its own topic (a recorder in the sim's process receives those without a socket) [-]
    record_batch: int = 0
    signals: StateSignals = dataclasses.field(default_factory=StateSignals)
    node_gains: NodeLoopGains = dataclasses.field(default_factory=NodeLoopGains)
    # the drive's following-error, current and speed trips (feed_twin/nodeset/protection.py)
    protection: ProtectionConfig = dataclasses.field(default_factory=ProtectionConfig)

    def __post_init__(self) -> None:
        AxisTopics(machine=self.machine, axis=self.axis)  # names must be valid ROS names
        require_positive("exchange_period_s", self.exchange_period_s)
        ns = self.exchange_period_s * NS_PER_S
        if abs(ns - round(ns)) > 1e-6:
            raise ValueError(
                f"exchange_period_s = {self.exchange_period_s!r}: must be a whole number of ns"
            )
        if not 0.0 <= self.settle_s <= 60.0:
            raise ValueError(f"settle_s = {self.settle_s!r}: must lie in [0, 60]")
        if isinstance(self.lookahead, bool) or not isinstance(self.lookahead, int):
            raise ValueError(f"lookahead = {self.lookahead!r}: must be a whole number")
        if not 1 <= self.lookahead <= 1000:
            raise ValueError(f"lookahead = {self.lookahead!r}: must lie in [1, 1000]")
        if isinstance(self.clock_divider, bool) or not isinstance(self.clock_divider, int):
            raise ValueError(f"clock_divider = {self.clock_divider!r}: must be a whole number")
        if not 1 <= self.clock_divider < self.lookahead:
            raise ValueError(
                f"clock_divider = {self.clock_divider!r}: must lie in [1, lookahead - 1] "
                f"= [1, {self.lookahead - 1}] so the NC stays ahead of the clock"
            )

        if self.recorder_host not in RECORDER_HOSTS:
            raise ValueError(
                f"recorder_host = {self.recorder_host!r}: must be one of "
                f"{', '.join(RECORDER_HOSTS)}"
            )
        for name, low, high in (
            ("record_batch", 0, 1000),
            ("exchange_cpu", -1, 1023),
            ("realtime_priority", 0, 99),
            ("cpu_latency_us", -1, 1_000_000),
            ("linuxcnc_nice", -20, 19),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ValueError(f"{name} = {value!r}: must be a whole number in [{low}, {high}]")

    @property
    def exchange_ns(self) -> int:
        return round(self.exchange_period_s * NS_PER_S)


def load_node_set_config(path: str | Path) -> NodeSetConfig:
    """The `ros:` section of an axis config file; defaults when the file has none."""
    data = load_yaml(path)
    return from_mapping(NodeSetConfig, data.get("ros", {}) or {}, source=str(path), path="ros")
