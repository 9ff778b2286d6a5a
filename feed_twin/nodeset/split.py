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
| voltage   | position + velocity + current   | u_d, u_q (MODE_VOLTAGE)     | modulation only    |

`voltage` is the full cascade outside the drive: the controller node also runs the FOC current
loop, at the exchange period (a loop cannot run faster than the messages that carry its
measurement), re-tuned by the technical optimum for the exchange's delay, and sends the d/q
voltage. The drive rotates that voltage with the rotor angle at every PWM period and modulates
it (SVPWM); its engine runs open loop. A 1 kHz current loop is far slower than a drive's, so
this mode shows what the drive's inner loop buys, it is not how a servo axis is run.

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
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from feed_twin.control.config import ControllerConfig
from feed_twin.control.loops import Cascade, PositionLoop, VelocityLoop, VelocitySetpoint
from feed_twin.core import signals as sig
from feed_twin.core.validate import require_positive
from feed_twin.io.config import from_mapping, load_yaml
from feed_twin.nodeset.protection import ProtectionConfig
from feed_twin.nodeset.topics import AxisTopics
from feed_twin.plant.assembly import PlantModel
from feed_twin.sim.program import set_nc_reference

Boundary = Literal["torque", "velocity", "position", "voltage"]
RecorderHost = Literal["auto", "sim", "own"]
RECORDER_HOSTS: tuple[RecorderHost, ...] = ("auto", "sim", "own")
# CiA 402 modes of operation, as in feed_twin_msgs/DriveCommand.
MODE_CSP = 8
MODE_CSV = 9
MODE_CST = 10
MODE_VOLTAGE = -1
BOUNDARY_MODES = {
    "position": MODE_CSP,
    "velocity": MODE_CSV,
    "torque": MODE_CST,
    "voltage": MODE_VOLTAGE,
}
NS_PER_S = 1_000_000_000


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
    boundary: Boundary = "torque"  # CiA 402 split, see the module docstring
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
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ValueError(f"{name} = {value!r}: must be a whole number in [{low}, {high}]")

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
    u_d_V: float = 0.0  # d-axis voltage (MODE_VOLTAGE) [V]
    u_q_V: float = 0.0  # q-axis voltage (MODE_VOLTAGE) [V]
    following_error_m: float = math.nan  # the controller's view, for the record [m]


def controller_node_config(
    config: ControllerConfig,
    exchange_period_s: float,
    gains: NodeLoopGains | None = None,
    *,
    with_current: bool = False,
) -> tuple[ControllerConfig, list[str]]:
    """The controller section the controller node runs: loops at least one exchange period.

    A loop faster than the exchange runs at the exchange period. The velocity loop then sees
    the exchange's delays (one period of transport, the hold, the estimator), so unless `gains`
    gives its gains it is re-tuned by the symmetric optimum (a = 2) for those delays and the
    position gain is capped at a quarter of its closed-loop bandwidth. With `with_current` (the
    full cascade) the current loop runs at the exchange period too, re-tuned by the technical
    optimum for 1.5 periods of delay (one of transport, half of hold), without the computation
    delay (the transport is that delay) and without dead-time compensation (a per-phase
    correction the drive's modulator would do). Returns the derived configuration and one note
    per change, for the node's log.
    """
    gains = gains or NodeLoopGains()
    notes: list[str] = []
    # keyword arguments of dataclasses.replace(config, ...): values of several types
    replace: dict[str, Any] = {"base_period_s": exchange_period_s, "current": None}
    current = config.current if with_current else None
    if with_current:
        if current is None:
            raise ValueError("boundary = 'voltage': the controller has no current section")
        replace["current"], note = _node_current_loop(current, exchange_period_s)
        replace["computation_delay"] = False
        notes.append(note)
    slowed: set[str] = set()
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
            slowed.add(name)
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
    velocity = replace.get("velocity")
    position = replace.get("position")
    if velocity is not None:
        Kp, Ti, Kv_cap = velocity.Kp, velocity.Ti_s, None
        if "velocity" in slowed and gains.velocity_Kp is None:
            Kp, Ti, Kv_cap = _retune_velocity(
                config, velocity, exchange_period_s, replace["current"] or config.current
            )
            notes.append(
                f"velocity loop re-tuned for the exchange: Kp {velocity.Kp:g} -> {Kp:.4g}, "
                f"Ti {velocity.Ti_s!r} -> {Ti:.4g} s"
            )
        Kp = gains.velocity_Kp if gains.velocity_Kp is not None else Kp
        Ti = gains.velocity_Ti_s if gains.velocity_Ti_s is not None else Ti
        replace["velocity"] = dataclasses.replace(velocity, Kp=Kp, Ti_s=Ti)
        if position is not None:
            Kv = position.Kv_1_s
            if gains.Kv_1_s is not None:
                Kv = gains.Kv_1_s
            elif Kv_cap is not None and Kv > Kv_cap:
                notes.append(f"position gain capped for the exchange: Kv {Kv:g} -> {Kv_cap:.4g}")
                Kv = Kv_cap
            replace["position"] = dataclasses.replace(position, Kv_1_s=Kv)
    try:
        derived = dataclasses.replace(config, **replace)
    except ValueError as exc:
        raise ValueError(
            f"the controller section cannot run at the exchange period {exchange_period_s!r} s: "
            f"{exc}"
        ) from None
    return derived, notes


def _node_current_loop(current, exchange_period_s: float):
    from feed_twin.control.tuning import tune_current_loop

    if current.period_s > exchange_period_s * (1.0 + 1e-9):
        raise ValueError(
            f"controller.current.period_s = {current.period_s!r}: longer than the exchange "
            f"period {exchange_period_s!r} s"
        )
    d = tune_current_loop(R_s=current.R_s_ohm, L=current.L_d_H, period_s=exchange_period_s)
    q = tune_current_loop(R_s=current.R_s_ohm, L=current.L_q_H, period_s=exchange_period_s)
    derived = dataclasses.replace(
        current,
        period_s=exchange_period_s,
        Kp_d_V_A=d.Kp_V_A,
        Ti_d_s=d.Ti_s,
        Kp_q_V_A=q.Kp_V_A,
        Ti_q_s=q.Ti_s,
        angle_advance_periods=0.0,
        dead_time_comp_V=0.0,
    )
    note = (
        f"current loop at the exchange period {exchange_period_s!r} s, re-tuned: Kp_q "
        f"{current.Kp_q_V_A:g} -> {q.Kp_V_A:.4g} V/A, bandwidth about {q.bandwidth_hz:.0f} Hz"
    )
    return derived, note


def _retune_velocity(
    config, velocity, exchange_period_s: float, current
) -> tuple[float, float, float]:
    from feed_twin.control.tuning import estimator_delay, tune_velocity_loop

    drive = config.drive
    # The closed current loop lags by about 2 T_sigma_i = 3 T_i (technical optimum).
    T_current = 3.0 * current.period_s if current is not None else 0.0
    est = velocity.estimator
    delay = estimator_delay(est.fir_taps, est.lowpass_hz, exchange_period_s) + exchange_period_s
    design = tune_velocity_loop(
        J_total_kg_m2=drive.J_total_kg_m2,
        K_t=drive.K_t,
        lead_m=drive.lead_m,
        period_s=exchange_period_s,
        T_current_s=T_current,
        estimator_delay_s=delay,
    )
    # Rule of thumb for a position loop around a PI velocity loop: Kv at most a quarter of the
    # velocity loop's closed-loop bandwidth keeps the setpoint response free of overshoot.
    return design.Kp, design.Ti_s, 2.0 * math.pi * design.bandwidth_hz / 4.0


class ControllerCore:
    """What the controller node computes per exchange: NC sample + drive feedback -> setpoint.

    `step(t_ns, nc, meas)` must be called at consecutive exchange instants (t = k * period).
    """

    def __init__(
        self,
        config: ControllerConfig,
        *,
        boundary: Boundary,
        exchange_period_s: float,
        gains: NodeLoopGains | None = None,
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
        self._cascade: Cascade | None = None
        self._ref = np.zeros(sig.REF_SIZE)
        if boundary == "voltage":
            node_config, self.notes = controller_node_config(
                config, exchange_period_s, gains, with_current=True
            )
            if node_config.position is None:
                raise ValueError(f"boundary = {boundary!r}: the controller has no position loop")
            self._cascade = Cascade(dataclasses.replace(node_config, mode="position"))
        elif boundary != "position":
            node_config, self.notes = controller_node_config(config, exchange_period_s, gains)
            if node_config.position is None:
                raise ValueError(f"boundary = {boundary!r}: the controller has no position loop")
            self._position = PositionLoop(node_config)
            if boundary == "torque":
                self._velocity = VelocityLoop(node_config)

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the loop kernels, so that the first exchange
        does not stall the node: one step on these loops, then back to their initial state.

        (A deep copy would not do: its parameter vectors are writable where the loops' own are
        read-only, a different numba signature, and the first real step compiled for ~10 ms.)
        """
        if self.boundary == "position":
            return
        nc = NcSample(t_ns=0, position_m=0.0, velocity_m_s=0.0, acceleration_m_s2=0.0, line=-1)
        self.step(0, nc, np.zeros(sig.MEAS_SIZE))
        for loop in (self._position, self._velocity, self._cascade):
            if loop is not None:
                loop.reset()

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
        ref = self._ref
        set_nc_reference(ref, nc.position_m, nc.velocity_m_s, nc.acceleration_m_s2)
        if self._cascade is not None:
            out = self._cascade.update(t, ref, meas)
            return DriveSetpoint(
                t_ns=t_ns,
                mode=self.mode,
                enable=True,
                position_m=float(out[sig.OUT_POS_REF_M]),
                velocity_m_s=float(out[sig.OUT_VEL_REF_M_S]),
                i_q_A=float(out[sig.OUT_I_Q_REF_A]),
                i_d_A=float(out[sig.OUT_I_D_REF_A]),
                u_d_V=float(out[sig.OUT_U_D_REF_V]),
                u_q_V=float(out[sig.OUT_U_Q_REF_V]),
                following_error_m=float(out[sig.OUT_FOLLOWING_ERROR_M]),
            )
        assert self._position is not None
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
        # CSP carries no acceleration: the drive's own feed-forward stays at zero
        set_nc_reference(out, setpoint.position_m, setpoint.velocity_m_s, 0.0)
        out[sig.REF_EFFORT_ADD] = setpoint.torque_Nm / K_t
    elif setpoint.mode != MODE_VOLTAGE:  # the voltage goes to the modulator, not the cascade
        raise ValueError(f"DriveCommand mode = {setpoint.mode!r}: not one of -1, 8, 9, 10")


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
        latest = self.latest_ns
        if samples and samples[0].t_ns <= t_ns and latest is not None and latest >= t_ns:
            self._last = samples[0]
            return samples[0]
        if self.finished and (self._last is not None or samples):
            last = samples[-1] if samples else self._last
            assert last is not None  # the condition above
            return NcSample(
                t_ns=t_ns,
                position_m=last.position_m,
                velocity_m_s=0.0,
                acceleration_m_s2=0.0,
                line=-1,
            )
        return None
