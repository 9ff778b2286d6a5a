"""The sim node's core (no rclpy): the engine advanced one exchange period per drive setpoint.

Protocol per exchange k (t_k = k * T, T the exchange period):
    the setpoint stamped t_k (computed by the controller from the feedback of t_{k-1}) is held
    over [t_k, t_{k+1}); the engine advances T / h base ticks; the sample it records at t_k
    (sensors as the drive latched them, plant truth) is returned.
So a feedback sample reaches the plant input one exchange period later, as on a fieldbus whose
drives latch their feedback at the cycle start (EtherCAT SYNC0) and apply the setpoint the
master computed from it at the next cycle. The first period runs with the drive enabled at
zero setpoint. `Lockstep` runs the same loop in-process, without DDS, for the cross-check.

In MODE_VOLTAGE (the full cascade in the controller node) the engine runs open loop and the
drive is its modulator: at every PWM period j of the exchange it rotates (u_d, u_q) to the
stator frame at the electrical angle p * phi(t_j) + offset, phi(t_j) = phi_k + omega_k * (j + 1/2) h
extrapolated from the rotor angle and speed at the exchange start (the error over 1 ms at
3 m/s^2 is below 0.01 rad electrical), and modulates with the cascade's own law
(feed_twin.control.transforms.modulate: SVPWM on u_dc of the previous exchange, dead-time
compensation with the controller section's values in the direction of the phase current
references, the setpoint's (i_d, i_q) at each PWM period's angle); a disabled drive applies
zero voltage (duties 1/2) with the stage off.

Why the references and not the phase currents latched at the exchange start: within the
compensation's band (u_comp / band = 10.16 V / 0.5 A, 20 V per A) the compensation is a feedback
of the phase current, and latched once per exchange it comes up to one exchange late while the
inverter's dead time takes its voltage off with the present current. At rest the phase currents
lie in that band, and the late 20 V/A against the current loop's 1.3 V/A drove a limit cycle of
the full cascade (700 um peak to peak at 12 Hz after a 10 mm move, with friction, backlash and
the inverter's dead time off as well; tests/test_nodeset_voltage_drive.py). A drive's own
16 kHz loop compensates from currents one PWM period old; a drive modulating setpoints of a
1 kHz loop uses the reference currents' direction, as the industrial modulators do whose
current measurement is noisy near zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from feed_twin.control.layout import disable, enable
from feed_twin.control.transforms import clarke, inverse_clarke, modulate, park
from feed_twin.core import signals as sig
from feed_twin.core.config import ConfigError
from feed_twin.nodeset.config import (
    NodeLoopGains,
    NodeSetConfig,
    StateSignals,
    load_node_set_config,
)
from feed_twin.nodeset.controller_core import ControllerCore
from feed_twin.nodeset.nc_buffer import NcBuffer
from feed_twin.nodeset.wire import (
    BOUNDARY_MODES,
    MODE_CST,
    MODE_VOLTAGE,
    NS_PER_S,
    DriveSetpoint,
    NcSample,
    drive_reference,
)

if TYPE_CHECKING:
    from feed_twin.gcode.trajectory import SampledTrajectory

MEAS_RECORD = tuple(f"meas.{n}" for n in sig.MEAS_NAMES)
OUT_RECORD = tuple(f"out.{n}" for n in sig.OUT_NAMES)
# The AxisState numbers after its header and axis label, in message order.
TRUTH_FIELDS = (
    "position_setpoint",
    "table_position",
    "table_velocity",
    "table_acceleration",
    "following_error",
    "motor_angle",
    "motor_velocity",
    "i_d",
    "i_q",
    "u_d",
    "u_q",
    "u_dc",
    "torque_em",
    "friction_force",
    "screw_force",
    "electrical_power",
    "mechanical_power",
)
# StateSignals fields read from the engine row, in the order `DriveHost.truth` unpacks them.
_SIGNAL_FIELDS = (
    "table_position",
    "table_velocity",
    "motor_angle",
    "motor_velocity",
    "i_d",
    "i_q",
    "u_d",
    "u_q",
    "u_dc",
    "i_dc",
    "torque_em",
    "friction_force",
    "screw_force",
)


@dataclass
class ExchangeSample:
    """What the sim publishes for one exchange instant t_k."""

    t_ns: int
    meas: np.ndarray  # MEAS_* vector as the drive latched it
    out: np.ndarray  # OUT_* vector of the drive's own controller (current loop internals)
    truth: dict[str, float] = field(default_factory=dict)  # AxisState field -> value
    feedback: dict[str, float] = field(default_factory=dict)  # AxisFeedback extras


class DriveHost:
    """An Engine (closed loop at the drive's CiA 402 mode) stepped one exchange at a time."""

    def __init__(
        self,
        engine,  # feed_twin.sim.engine.Engine, built with output_period_s = exchange period
        *,
        exchange_period_s: float,
        K_t: float,
        signals: StateSignals,
        pole_pairs: int = 0,
        encoder_offset_rad: float = 0.0,
        start_position_m: float = 0.0,
        dead_time_comp_V: float = 0.0,
        dead_time_comp_band_A: float = 0.5,
        mode: int = MODE_CST,  # the CiA 402 mode the engine's cascade runs (MODE_CSP/CSV/CST)
    ) -> None:
        self.engine = engine
        self.dead_time_comp_V = dead_time_comp_V
        self.dead_time_comp_band_A = dead_time_comp_band_A
        ticks = exchange_period_s / engine.h
        if abs(ticks - round(ticks)) > 1e-9 * ticks or round(ticks) < 1:
            raise ValueError(
                f"exchange_period_s = {exchange_period_s!r}: must be a multiple of the engine's "
                f"base period {engine.h!r} s"
            )
        if engine.dec != round(ticks):
            raise ValueError(
                f"the engine records every {engine.dec} ticks; the drive host needs one sample "
                f"per exchange ({round(ticks)} ticks)"
            )
        self.ticks = round(ticks)
        self.exchange_ns = round(exchange_period_s * NS_PER_S)
        self.K_t = K_t
        self.signals = signals
        self.pole_pairs = pole_pairs
        self.encoder_offset_rad = encoder_offset_rad
        names = engine.record_names
        self._index = {n: i for i, n in enumerate(names)}
        missing = [n for n in (*signals.names(), *MEAS_RECORD, *OUT_RECORD) if n not in names]
        if missing:
            raise ValueError(
                f"engine signal(s) {', '.join(missing)} not recorded; check ros.signals "
                f"against the plant's component names"
            )
        counts = [
            engine.p[engine.model.param_index[n]]
            for n in engine.model.param_names
            if n.endswith(".step") and n.split(".")[0] in ("encoder",)
        ]
        self.encoder_step_rad = float(counts[0]) if counts else 0.0
        self._meas_idx = np.array([self._index[n] for n in MEAS_RECORD])
        self._i_fault = self._index[f"out.{sig.OUT_NAMES[sig.OUT_FAULT]}"]
        self._i_enabled = self._index[f"out.{sig.OUT_NAMES[sig.OUT_ENABLED]}"]
        self._i_u_ref = (
            self._index[f"out.{sig.OUT_NAMES[sig.OUT_U_D_REF_V]}"],
            self._index[f"out.{sig.OUT_NAMES[sig.OUT_U_Q_REF_V]}"],
        )
        # One fancy-index and one multiply give every AxisState signal; a signal the plant does
        # not have reads slot 0 times NaN.
        names = [getattr(signals, f) for f in _SIGNAL_FIELDS]
        self._signal_idx = np.array([self._index[n.lstrip("-")] if n else 0 for n in names])
        self._signal_sign = np.array(
            [math.nan if not n else (-1.0 if n[0] == "-" else 1.0) for n in names]
        )
        self._row = np.zeros((1, sig.REF_SIZE))  # the reference held over an exchange
        self._prev_v: float | None = None
        self.modulator = engine.controller is None  # open loop: MODE_VOLTAGE only
        self._drive = np.zeros((self.ticks, sig.OUT_SIZE))
        self._u_dc: float | None = None
        if self.modulator:
            states = engine.model.state_names
            for name in (signals.motor_angle, signals.motor_velocity):
                if name not in states:
                    raise ValueError(
                        f"the voltage-mode drive needs the rotor angle and speed as plant states; "
                        f"{name!r} is not one (states: {', '.join(states[:8])}, ...)"
                    )
            self._i_phi = states.index(signals.motor_angle)
            self._i_omega = states.index(signals.motor_velocity)
        # Until the first command arrives the drive holds where the table stands, in its own
        # mode (a CSP drive given 0 m would trip on the following error; a modulator applies
        # zero voltage).
        self.setpoint = DriveSetpoint(
            t_ns=0,
            mode=MODE_VOLTAGE if self.modulator else mode,
            enable=True,
            position_m=start_position_m,
        )
        self.k = 0

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels before the first exchange."""
        self.engine.advance(0)
        clarke(0.0, 0.0, 0.0)
        park(0.0, 0.0, 0.0)
        if self.modulator:
            modulate(0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0)
            inverse_clarke(0.0, 0.0)

    @staticmethod
    def record_names(signals: StateSignals) -> tuple[str, ...]:
        return tuple(dict.fromkeys((*signals.names(), *MEAS_RECORD, *OUT_RECORD)))

    @property
    def t_ns(self) -> int:
        return self.k * self.exchange_ns

    def advance(self, setpoint: DriveSetpoint | None) -> tuple[int, np.ndarray]:
        """Hold `setpoint` (None: keep the previous one) over one exchange; returns the exchange
        instant t_k [ns] and the engine row recorded there (names: `engine.record_names`; valid
        until the next call)."""
        if setpoint is not None:
            if (setpoint.mode == MODE_VOLTAGE) != self.modulator:
                raise ValueError(
                    f"DriveCommand mode = {setpoint.mode!r}: this drive takes "
                    f"{'only MODE_VOLTAGE (-1)' if self.modulator else 'modes 8, 9, 10'} "
                    f"(ros.boundary of the sim and the controller differ?)"
                )
            self.setpoint = setpoint
        sp = self.setpoint
        if self.modulator:
            row = self.engine.advance(self.ticks, drive=self._modulate(sp)).data[0]
        else:
            (enable if sp.enable else disable)(self.engine.cs)
            drive_reference(sp, self.K_t, self._row[0])
            row = self.engine.advance_held(self._row)
        t_ns = self.t_ns
        self.k += 1
        return t_ns, row

    def _modulate(self, sp: DriveSetpoint) -> np.ndarray:
        """Open-loop drive rows (duties, enabled) of one exchange for a MODE_VOLTAGE setpoint."""
        rows = self._drive
        rows[:] = 0.0
        rows[:, sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1] = 0.5
        if not sp.enable:
            return rows
        rows[:, sig.OUT_ENABLED] = 1.0
        if self._u_dc is None or (sp.u_d_V == 0.0 and sp.u_q_V == 0.0):
            return rows
        phi = float(self.engine.x[self._i_phi])
        omega = float(self.engine.x[self._i_omega])
        h = self.engine.h
        for j in range(self.ticks):
            theta_e = self.pole_pairs * (phi + omega * (j + 0.5) * h) + self.encoder_offset_rad
            cos_e, sin_e = math.cos(theta_e), math.sin(theta_e)
            # the compensation's direction: the phase current references (module docstring)
            i_a, i_b, i_c = inverse_clarke(
                cos_e * sp.i_d_A - sin_e * sp.i_q_A, sin_e * sp.i_d_A + cos_e * sp.i_q_A
            )
            rows[j, sig.OUT_DUTY_A : sig.OUT_DUTY_C + 1] = modulate(
                sp.u_d_V,
                sp.u_q_V,
                cos_e,
                sin_e,
                i_a,
                i_b,
                i_c,
                self.dead_time_comp_V,
                self.dead_time_comp_band_A,
                self._u_dc,
            )
        return rows

    def feedback(self, row: np.ndarray) -> tuple[list[float], int, float, float, float]:
        """What the drive reports at a row: (MEAS_* values, encoder counts, i_d [A], i_q [A],
        following error setpoint - scale [m]); i_d, i_q are NaN without a current loop."""
        meas = row[self._meas_idx].tolist()
        self._u_dc = meas[sig.MEAS_U_DC_V]
        theta = meas[sig.MEAS_THETA_ENC_RAD]
        counts = round(theta / self.encoder_step_rad) if self.encoder_step_rad > 0.0 else 0
        if self.pole_pairs:
            theta_e = self.pole_pairs * theta + self.encoder_offset_rad
            alpha, beta = clarke(meas[sig.MEAS_I_A], meas[sig.MEAS_I_B], meas[sig.MEAS_I_C])
            i_d, i_q = park(alpha, beta, theta_e)
            i_d, i_q = float(i_d), float(i_q)
        else:
            i_d = i_q = math.nan
        error = self.setpoint.position_m - meas[sig.MEAS_X_SCALE_M]
        return meas, counts, i_d, i_q, error

    def voltage_refs(self, row: np.ndarray) -> tuple[float, float]:
        """(u_d, u_q) [V] the drive's current controller commands at a row (a drive scope's
        voltage references: the dead time and the device drop are what the inverter then takes
        off them); NaN for a drive without a current loop (force/torque source)."""
        if not self.pole_pairs:
            return math.nan, math.nan
        return float(row[self._i_u_ref[0]]), float(row[self._i_u_ref[1]])

    def fault(self, row: np.ndarray) -> tuple[int, bool]:
        """(FAULT_* code, power stage enabled) of the drive at a row."""
        return int(row[self._i_fault]), bool(row[self._i_enabled] > 0.5)

    def truth(self, row: np.ndarray) -> list[float]:
        """The AxisState numbers (TRUTH_FIELDS order) of the row of this exchange.

        Call once per exchange, in order: the acceleration is the difference quotient of the
        table velocity over the exchange period.
        """
        (x, v, phi, omega, i_d, i_q, u_d, u_q, u_dc, i_dc, tau, f_friction, f_screw) = (
            row[self._signal_idx] * self._signal_sign
        ).tolist()
        acc = 0.0 if self._prev_v is None else (v - self._prev_v) * NS_PER_S / self.exchange_ns
        self._prev_v = v
        x_r = self.setpoint.position_m
        return [
            x_r, x, v, acc, x_r - x, phi, omega, i_d, i_q, u_d, u_q, u_dc, tau,
            f_friction, f_screw, u_dc * i_dc, tau * omega,
        ]  # fmt: skip

    def step(self, setpoint: DriveSetpoint | None) -> ExchangeSample:
        """`advance`, then everything the sim publishes for that exchange as one sample."""
        t_ns, row = self.advance(setpoint)
        meas, counts, i_d, i_q, error = self.feedback(row)
        u_d_ref, u_q_ref = self.voltage_refs(row)
        return ExchangeSample(
            t_ns=t_ns,
            meas=np.array(meas),
            out=np.array([row[self._index[n]] for n in OUT_RECORD]),
            truth=dict(zip(TRUTH_FIELDS, self.truth(row), strict=True)),
            feedback={
                "encoder_counts": counts,
                "i_d": i_d,
                "i_q": i_q,
                "u_d_ref": u_d_ref,
                "u_q_ref": u_q_ref,
                "following_error": error,
            },
        )


def nc_samples(
    t_s: np.ndarray, x: np.ndarray, v: np.ndarray, a: np.ndarray, line: np.ndarray
) -> list[NcSample]:
    return [
        NcSample(
            t_ns=round(t * NS_PER_S),
            position_m=float(xi),
            velocity_m_s=float(vi),
            acceleration_m_s2=float(ai),
            line=int(li),
        )
        for t, xi, vi, ai, li in zip(t_s, x, v, a, line, strict=True)
    ]


class Lockstep:
    """The node set's exchange loop in one process, for the cross-check and for tests.

    Uses the same `ControllerCore` and `DriveHost` as the controller and sim nodes, with the
    same hold rule for the NC stream (the last setpoint at standstill after the program).
    """

    def __init__(self, controller: ControllerCore, host: DriveHost, ros: NodeSetConfig) -> None:
        self.controller = controller
        self.host = host
        self.ros = ros

    @classmethod
    def for_config(cls, config_path: str | Path, *, gains: NodeLoopGains | None = None) -> Lockstep:
        """The controller node's core and the sim node's drive host of an axis config, as the
        node set builds them (`gains`: the node's loop options, the config's when None)."""
        from feed_twin.sim.config import load_axis_config

        ros = load_node_set_config(config_path)
        axis = load_axis_config(config_path)
        if axis.controller is None:
            raise ConfigError(f"{config_path}: the node set needs a controller section")
        controller = ControllerCore(
            axis.controller,
            boundary=ros.boundary,
            exchange_period_s=ros.exchange_period_s,
            gains=gains,
        )
        return cls(controller, build_drive_host(config_path, ros), ros)

    def run_trajectory(
        self, trajectory: SampledTrajectory, *, until_ns: int, axis: str = "X"
    ) -> list[ExchangeSample]:
        """`run` on one axis of a planned program (feed_twin.gcode)."""
        x, v, a = trajectory.axis(axis)
        return self.run(nc_samples(trajectory.t_s, x, v, a, trajectory.line), until_ns=until_ns)

    def run(self, commands: list[NcSample], *, until_ns: int) -> list[ExchangeSample]:
        """Exchanges from t = 0 while t <= until_ns, the whole NC stream known in advance."""
        buffer = NcBuffer()
        for c in commands:
            buffer.add(c)
        buffer.finish()
        samples: list[ExchangeSample] = []
        setpoint: DriveSetpoint | None = None
        while self.host.t_ns <= until_ns:
            sample = self.host.step(setpoint)
            samples.append(sample)
            t_next = sample.t_ns + self.host.exchange_ns
            nc = buffer.for_time(t_next)
            if nc is None:
                raise ValueError(f"no NC setpoint for t = {t_next} ns (before the program)")
            setpoint = self.controller.step(t_next, nc, sample.meas)
        return samples


def build_drive_host(config_path: str | Path, ros: NodeSetConfig) -> DriveHost:
    """The engine of the axis config at the drive's CiA 402 mode, wrapped for exchanges."""
    from feed_twin.sim.config import build_engine, load_axis_config

    axis = load_axis_config(config_path)
    if axis.controller is None:
        raise ConfigError(f"{config_path}: the sim node needs a controller section")
    # The full cascade leaves the drive only its modulator: the engine runs open loop.
    closed = ros.boundary != "voltage"
    mode = ros.boundary if closed else None
    probe = build_engine(axis, closed_loop=closed, mode=mode, output_period_s=ros.exchange_period_s)
    try:
        signals = ros.signals.resolve(axis.plant, probe.all_names)
    except ValueError as exc:
        raise ConfigError(f"{config_path}: {exc}") from None
    names = DriveHost.record_names(signals)
    unknown = [n for n in names if n not in probe.all_names]
    if unknown:
        raise ConfigError(
            f"{config_path}: ros.signals: {', '.join(unknown)}: not signals of this plant "
            f"(for example {', '.join(probe.all_names[:6])}, ...)"
        )
    engine = build_engine(
        axis,
        closed_loop=closed,
        mode=mode,
        record=names,
        output_period_s=ros.exchange_period_s,
    )
    # The table coordinate is the machine coordinate of the twin axis: the plant starts at
    # rest where the NC program starts (position-dependent screw stiffness needs the real place).
    start = 0.0
    if axis.nc is not None:
        from feed_twin.gcode.config import nc_config_from_mapping

        start = nc_config_from_mapping(axis.nc, source=str(config_path)).twin_start_position_m
        body = (signals.table_position or "").lstrip("-").split(".")[0]
        engine.reset(positions={body: start})
    current = axis.controller.current
    return DriveHost(
        engine,
        exchange_period_s=ros.exchange_period_s,
        K_t=axis.controller.drive.K_t,
        signals=signals,
        pole_pairs=current.pole_pairs if current is not None else 0,
        encoder_offset_rad=current.encoder_offset_rad if current is not None else 0.0,
        start_position_m=start,
        dead_time_comp_V=current.dead_time_comp_V if current is not None else 0.0,
        dead_time_comp_band_A=current.dead_time_comp_band_A if current is not None else 0.5,
        mode=BOUNDARY_MODES[ros.boundary],
    )
