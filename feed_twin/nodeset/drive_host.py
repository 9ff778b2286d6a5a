"""The sim node's core (no rclpy): the engine advanced one exchange period per drive setpoint.

Protocol per exchange k (t_k = k * T, T the exchange period):
    the setpoint stamped t_k (computed by the controller from the feedback of t_{k-1}) is held
    over [t_k, t_{k+1}); the engine advances T / h base ticks; the sample it records at t_k
    (sensors as the drive latched them, plant truth) is returned.
So a feedback sample reaches the plant input one exchange period later, as on a fieldbus whose
drives latch their feedback at the cycle start (EtherCAT SYNC0) and apply the setpoint the
master computed from it at the next cycle. The first period runs with the drive enabled at
zero setpoint. `Lockstep` runs the same loop in-process, without DDS, for the cross-check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from feed_twin.control import signals as sig
from feed_twin.control.layout import disable, enable
from feed_twin.control.transforms import clarke, park
from feed_twin.nodeset.split import (
    MODE_CST,
    NS_PER_S,
    ControllerCore,
    DriveSetpoint,
    NcBuffer,
    NcSample,
    NodeSetConfig,
    StateSignals,
    drive_reference,
)

MEAS_RECORD = tuple(f"meas.{n}" for n in sig.MEAS_NAMES)
OUT_RECORD = tuple(f"out.{n}" for n in sig.OUT_NAMES)


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
    ) -> None:
        self.engine = engine
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
        self._ref = np.zeros((self.ticks, sig.REF_SIZE))
        self._row = np.zeros(sig.REF_SIZE)
        self._prev_v: float | None = None
        # Until the first command arrives the drive holds where the table stands.
        self.setpoint = DriveSetpoint(
            t_ns=0, mode=MODE_CST, enable=True, position_m=start_position_m
        )
        self.k = 0

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the kernels before the first exchange."""
        self.engine.advance(0)
        clarke(0.0, 0.0, 0.0)
        park(0.0, 0.0, 0.0)

    @staticmethod
    def record_names(signals: StateSignals) -> tuple[str, ...]:
        return tuple(dict.fromkeys((*signals.names(), *MEAS_RECORD, *OUT_RECORD)))

    @property
    def t_ns(self) -> int:
        return self.k * self.exchange_ns

    def step(self, setpoint: DriveSetpoint | None) -> ExchangeSample:
        """Hold `setpoint` (None: keep the previous one) over one exchange; sample at its start."""
        if setpoint is not None:
            self.setpoint = setpoint
        sp = self.setpoint
        (enable if sp.enable else disable)(self.engine.cs)
        drive_reference(sp, self.K_t, self._row)
        self._ref[:] = self._row
        result = self.engine.advance(self.ticks, self._ref)
        row = result.data[0]
        t_ns = self.t_ns
        self.k += 1
        return self._sample(t_ns, row, sp)

    def _value(self, row: np.ndarray, name: str) -> float:
        if not name:
            return math.nan
        if name[0] == "-":
            return -float(row[self._index[name[1:]]])
        return float(row[self._index[name]])

    def _sample(self, t_ns: int, row: np.ndarray, sp: DriveSetpoint) -> ExchangeSample:
        meas = np.array([row[self._index[n]] for n in MEAS_RECORD])
        out = np.array([row[self._index[n]] for n in OUT_RECORD])
        s = self.signals
        v = self._value(row, s.table_velocity)
        period = self.exchange_ns / NS_PER_S
        acc = 0.0 if self._prev_v is None else (v - self._prev_v) / period
        self._prev_v = v
        x = self._value(row, s.table_position)
        tau = self._value(row, s.torque_em)
        omega = self._value(row, s.motor_velocity)
        u_dc = self._value(row, s.u_dc)
        truth = {
            "position_setpoint": sp.position_m,
            "table_position": x,
            "table_velocity": v,
            "table_acceleration": acc,
            "following_error": sp.position_m - x,
            "motor_angle": self._value(row, s.motor_angle),
            "motor_velocity": omega,
            "i_d": self._value(row, s.i_d),
            "i_q": self._value(row, s.i_q),
            "u_d": self._value(row, s.u_d),
            "u_q": self._value(row, s.u_q),
            "u_dc": u_dc,
            "torque_em": tau,
            "friction_force": self._value(row, s.friction_force),
            "screw_force": self._value(row, s.screw_force),
            "electrical_power": u_dc * self._value(row, s.i_dc),
            "mechanical_power": tau * omega,
        }
        theta = float(meas[sig.MEAS_THETA_ENC_RAD])
        theta_e = self.pole_pairs * theta + self.encoder_offset_rad
        alpha, beta = clarke(meas[sig.MEAS_I_A], meas[sig.MEAS_I_B], meas[sig.MEAS_I_C])
        i_d, i_q = park(alpha, beta, theta_e)
        feedback = {
            "encoder_counts": (
                round(theta / self.encoder_step_rad) if self.encoder_step_rad > 0.0 else 0
            ),
            "i_d": float(i_d) if self.pole_pairs else math.nan,
            "i_q": float(i_q) if self.pole_pairs else math.nan,
            "following_error": sp.position_m - float(meas[sig.MEAS_X_SCALE_M]),
        }
        return ExchangeSample(t_ns=t_ns, meas=meas, out=out, truth=truth, feedback=feedback)


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
