"""The controller/drive split of the node set, as plain Python (no rclpy): what crosses the wire.

A real servo drive closes its current loop inside, at PWM rate; the controller above it sends
one setpoint per fieldbus cycle. The node set follows that (CiA 402): the controller node runs
the outer loops once per exchange period (1 ms by default) and sends a `DriveSetpoint`; the sim
node runs the current loop and the inverter with the plant. `boundary` chooses the split:

| boundary  | controller node runs            | DriveCommand carries        | drive (sim) runs   |
|-----------|---------------------------------|-----------------------------|--------------------|
| torque    | position + velocity loops       | i_q (CST)                   | current loop       |
| velocity  | position loop                   | velocity + torque FF (CSV)  | velocity + current |
| position  | nothing (passes NC setpoints)   | position + velocity (CSP)   | all loops          |

Loops that run in the controller node run at the exchange period: a loop cannot run faster than
the messages that carry its measurement. `controller_node_config` derives that configuration from
the axis's `controller:` section and says what it changed.

The nodes only convert messages to and from these classes, so the in-process `Lockstep` run
below (used by the cross-check test) computes exactly what the node set computes.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from feed_twin.control import signals as sig
from feed_twin.control.cascade import ControllerConfig
from feed_twin.control.loops import PositionLoop, VelocityLoop, VelocitySetpoint
from feed_twin.io.config import from_mapping, load_yaml, require_positive

Boundary = Literal["torque", "velocity", "position"]
# CiA 402 modes of operation, as in feed_twin_msgs/DriveCommand.
MODE_CSP = 8
MODE_CSV = 9
MODE_CST = 10
BOUNDARY_MODES = {"position": MODE_CSP, "velocity": MODE_CSV, "torque": MODE_CST}
NS_PER_S = 1_000_000_000


@dataclass(frozen=True, kw_only=True)
class StateSignals:
    """Engine signal names behind the AxisState fields ("" where the plant has no such signal).

    The defaults name the components of config/axis_default.yaml; another plant sets its own
    in the `ros.signals` section.
    """

    table_position: str = "table.s"
    table_velocity: str = "table.v"
    motor_angle: str = "motor.phi"
    motor_velocity: str = "motor.omega"
    i_d: str = "motor.i_d"
    i_q: str = "motor.i_q"
    u_d: str = "motor.u_d"
    u_q: str = "motor.u_q"
    u_dc: str = "bus.u_dc"
    i_dc: str = "bus.i_dc"
    torque_em: str = "motor.tau_e"
    friction_force: str = "guides.force"
    screw_force: str = "backlash.force"

    def names(self) -> tuple[str, ...]:
        return tuple(v for v in vars(self).values() if v)


@dataclass(frozen=True, kw_only=True)
class NodeSetConfig:
    """The `ros:` section of an axis config: names, exchange rate and controller/drive split."""

    machine: str = "cnc"  # first namespace level
    axis: str = "x"  # second namespace level
    exchange_period_s: float = 1.0e-3  # controller <-> drive message period [s]
    boundary: Boundary = "torque"  # CiA 402 split, see the module docstring
    settle_s: float = 0.2  # simulated time after the program's end [s]
    lookahead: int = 20  # NC setpoints published ahead of the simulation clock [-]
    signals: StateSignals = dataclasses.field(default_factory=StateSignals)

    def __post_init__(self) -> None:
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

    @property
    def exchange_ns(self) -> int:
        return round(self.exchange_period_s * NS_PER_S)


@dataclass(frozen=True, kw_only=True)
class NcSample:
    """One NC setpoint (AxisCommand), load side, SI."""

    t_ns: int
    position_m: float
    velocity_m_s: float
    acceleration_m_s2: float
    line: int


@dataclass(frozen=True, kw_only=True)
class DriveSetpoint:
    """One DriveCommand: the fields its CiA 402 mode uses; the others are 0."""

    t_ns: int
    mode: int  # MODE_*
    enable: bool
    position_m: float = 0.0
    velocity_m_s: float = 0.0
    torque_Nm: float = 0.0
    i_q_A: float = 0.0
    i_d_A: float = 0.0
    following_error_m: float = math.nan  # the controller's view, for the record [m]


def controller_node_config(
    config: ControllerConfig, exchange_period_s: float
) -> tuple[ControllerConfig, list[str]]:
    """The controller section the controller node runs: loops at least one exchange period.

    Returns the derived configuration and one note per change, for the node's log.
    """
    notes: list[str] = []
    replace: dict[str, object] = {"base_period_s": exchange_period_s, "current": None}
    for name in ("position", "velocity"):
        loop = getattr(config, name)
        if loop is None:
            continue
        period = loop.period_s
        ratio = period / exchange_period_s
        if ratio < 1.0 - 1e-9:
            notes.append(
                f"controller.{name}.period_s = {period!r} s runs at the exchange period "
                f"{exchange_period_s!r} s in the controller node"
            )
            period = exchange_period_s
        elif abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(
                f"controller.{name}.period_s = {period!r}: must be a multiple of the exchange "
                f"period {exchange_period_s!r} s to run in the controller node"
            )
        replace[name] = dataclasses.replace(loop, period_s=period)
    if config.nc_period_s < exchange_period_s - 1e-12:
        raise ValueError(
            f"controller.nc_period_s = {config.nc_period_s!r}: must not be shorter than the "
            f"exchange period {exchange_period_s!r} s"
        )
    try:
        derived = dataclasses.replace(config, **replace)
    except ValueError as exc:
        raise ValueError(
            f"the controller section cannot run at the exchange period {exchange_period_s!r} s: "
            f"{exc}"
        ) from None
    return derived, notes


class ControllerCore:
    """What the controller node computes per exchange: NC sample + drive feedback -> setpoint.

    `step(t_ns, nc, meas)` must be called at consecutive exchange instants (t = k * period).
    """

    def __init__(
        self, config: ControllerConfig, *, boundary: Boundary, exchange_period_s: float
    ) -> None:
        if boundary not in BOUNDARY_MODES:
            raise ValueError(
                f"boundary = {boundary!r}: must be one of {', '.join(map(repr, BOUNDARY_MODES))}"
            )
        self.boundary = boundary
        self.mode = BOUNDARY_MODES[boundary]
        self.drive = config.drive
        self.exchange_period_s = exchange_period_s
        self.notes: list[str] = []
        self._position: PositionLoop | None = None
        self._velocity: VelocityLoop | None = None
        self._ref = np.zeros(sig.REF_SIZE)
        if boundary != "position":
            node_config, self.notes = controller_node_config(config, exchange_period_s)
            if node_config.position is None:
                raise ValueError(f"boundary = {boundary!r}: the controller has no position loop")
            self._position = PositionLoop(node_config)
            if boundary == "torque":
                self._velocity = VelocityLoop(node_config)

    def step(self, t_ns: int, nc: NcSample, meas: np.ndarray) -> DriveSetpoint:
        t = t_ns / NS_PER_S
        if self.boundary == "position":
            return DriveSetpoint(
                t_ns=t_ns,
                mode=self.mode,
                enable=True,
                position_m=nc.position_m,
                velocity_m_s=nc.velocity_m_s,
            )
        assert self._position is not None
        ref = self._ref
        ref[sig.REF_POS_M] = nc.position_m
        ref[sig.REF_VEL_M_S] = nc.velocity_m_s
        ref[sig.REF_ACC_M_S2] = nc.acceleration_m_s2
        pos = self._position.update(t, ref, meas)
        if self._velocity is None:
            return DriveSetpoint(
                t_ns=t_ns,
                mode=self.mode,
                enable=True,
                position_m=pos.pos_ref_m,
                velocity_m_s=pos.vel_ref_m_s,
                torque_Nm=pos.effort_ff * self.drive.K_t,
                following_error_m=pos.following_error_m,
            )
        effort = self._velocity.update(
            t, VelocitySetpoint(vel_m_s=pos.vel_ref_m_s, effort_ff=pos.effort_ff), meas
        )
        return DriveSetpoint(
            t_ns=t_ns,
            mode=self.mode,
            enable=True,
            position_m=pos.pos_ref_m,
            velocity_m_s=pos.vel_ref_m_s,
            torque_Nm=effort * self.drive.K_t,
            i_q_A=effort,
            following_error_m=pos.following_error_m,
        )


def drive_reference(setpoint: DriveSetpoint, K_t: float, out: np.ndarray) -> None:
    """Fill the REF_* vector the simulated drive's cascade reads from a DriveSetpoint."""
    out[:] = 0.0
    if setpoint.mode == MODE_CST:
        out[sig.REF_I_Q_EXT_A] = setpoint.i_q_A
    elif setpoint.mode == MODE_CSV:
        out[sig.REF_VEL_EXT_M_S] = setpoint.velocity_m_s
        out[sig.REF_EFFORT_ADD] = setpoint.torque_Nm / K_t
    elif setpoint.mode == MODE_CSP:
        out[sig.REF_POS_M] = setpoint.position_m
        out[sig.REF_VEL_M_S] = setpoint.velocity_m_s
        out[sig.REF_EFFORT_ADD] = setpoint.torque_Nm / K_t
    else:
        raise ValueError(f"DriveCommand mode = {setpoint.mode!r}: not one of 8, 9, 10")


def load_node_set_config(path: str | Path) -> NodeSetConfig:
    """The `ros:` section of an axis config file; defaults when the file has none."""
    data = load_yaml(path)
    return from_mapping(NodeSetConfig, data.get("ros", {}) or {}, source=str(path), path="ros")


class NcBuffer:
    """The NC setpoints received so far, and the rule that picks the one for an exchange time.

    The setpoint for t is the latest one stamped <= t, known once a setpoint stamped >= t has
    arrived (topics deliver in order). After the program has finished the last position is held
    at standstill (line -1), as a control does at program end.
    """

    def __init__(self) -> None:
        self._samples: collections.deque[NcSample] = collections.deque()
        self.latest_ns: int | None = None
        self.finished = False
        self._last: NcSample | None = None

    def add(self, sample: NcSample) -> None:
        self._samples.append(sample)
        self.latest_ns = sample.t_ns

    def finish(self) -> None:
        self.finished = True

    def for_time(self, t_ns: int) -> NcSample | None:
        samples = self._samples
        while len(samples) > 1 and samples[1].t_ns <= t_ns:
            samples.popleft()
        if samples and samples[0].t_ns <= t_ns and self.latest_ns >= t_ns:
            self._last = samples[0]
            return samples[0]
        if self.finished and (self._last is not None or samples):
            last = samples[-1] if samples else self._last
            return NcSample(
                t_ns=t_ns,
                position_m=last.position_m,
                velocity_m_s=0.0,
                acceleration_m_s2=0.0,
                line=-1,
            )
        return None
