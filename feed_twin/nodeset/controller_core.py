"""`ControllerCore`: what the controller node computes per exchange, as plain Python (no rclpy).

Loops that run in the controller node run at the exchange period: a loop cannot run faster than
the messages that carry its measurement. `controller_node_config` derives that configuration from
the axis's `controller:` section and says what it changed.

The nodes only convert messages to and from these classes, so the in-process `Lockstep` run
(feed_twin/nodeset/drive_host.py, used by the cross-check test) computes exactly what the node
set computes.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from feed_twin.control.config import ControllerConfig
from feed_twin.control.loops import Cascade, PositionLoop, VelocityLoop, VelocitySetpoint
from feed_twin.core import signals as sig
from feed_twin.nodeset.config import Boundary, NodeLoopGains
from feed_twin.nodeset.reference_delay import DelayedReference
from feed_twin.nodeset.wire import BOUNDARY_MODES, NS_PER_S, DriveSetpoint, NcSample
from feed_twin.sim.program import set_nc_reference


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
    optimum for 1.5 periods of delay (one of transport, half of hold), its zero on the back-EMF
    feed-forward's residual resistance (`_node_current_loop`), without the computation delay
    (the transport is that delay) and without dead-time compensation (a per-phase correction
    the drive's modulator does). Returns the derived configuration and one note per change,
    for the node's log.
    """
    gains = gains or NodeLoopGains()
    notes: list[str] = []
    # keyword arguments of dataclasses.replace(config, ...): values of several types
    replace: dict[str, Any] = {"base_period_s": exchange_period_s, "current": None}
    current = config.current if with_current else None
    if with_current:
        if current is None:
            raise ValueError("boundary = 'voltage': the controller has no current section")
        replace["current"], note = _node_current_loop(config, current, exchange_period_s)
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


def _node_current_loop(config: ControllerConfig, current, exchange_period_s: float):
    """The current loop at the exchange period: technical optimum on R_s + R_ff.

    The back-EMF feed-forward p psi_pm omega comes from the velocity estimate, tau_ff late (the
    estimator's delay, one exchange of transport, half of hold: 2.5 ms at 1 ms). What it leaves,
    p psi_pm (omega(t - tau_ff) - omega(t)) = -p psi_pm tau_ff K_t i_q / J at low frequency, is
    a resistance R_ff = p psi_pm K_t tau_ff / J in series with R_s (1.04 Ohm on the default
    axis, three times R_s: its mechanical time constant R_s J / (p psi_pm K_t) = 0.84 ms is
    shorter than tau_ff). With the PI's zero at R_s / L the closed loop lagged 26 deg at 13 Hz
    (0.68 in gain) where the velocity loop's re-tune counts on a 3 T lag (14 deg); with the zero
    at (R_s + R_ff) / L it is that lag within 1.5 deg up to 31 Hz
    (tests/test_nodeset_voltage_drive.py). Without a back-EMF feed-forward or a velocity loop
    the zero stays at R_s / L.
    """
    from feed_twin.control.tuning import estimator_delay, tune_current_loop

    if current.period_s > exchange_period_s * (1.0 + 1e-9):
        raise ValueError(
            f"controller.current.period_s = {current.period_s!r}: longer than the exchange "
            f"period {exchange_period_s!r} s"
        )
    R_ff = 0.0
    velocity = config.velocity
    if current.back_emf_ff and velocity is not None:
        est = velocity.estimator
        tau_ff = estimator_delay(est.fir_taps, est.lowpass_hz, exchange_period_s)
        tau_ff += 1.5 * exchange_period_s
        k_e = current.pole_pairs * current.psi_pm_Vs  # back-EMF per rad/s of the rotor [V s]
        R_ff = k_e * config.drive.K_t * tau_ff / config.drive.J_total_kg_m2
    R = current.R_s_ohm + R_ff
    d = tune_current_loop(R_s=R, L=current.L_d_H, period_s=exchange_period_s)
    q = tune_current_loop(R_s=R, L=current.L_q_H, period_s=exchange_period_s)
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
        f"{current.Kp_q_V_A:g} -> {q.Kp_V_A:.4g} V/A, Ti_q {current.Ti_q_s:g} -> {q.Ti_s:.4g} s "
        f"(zero on R_s + {R_ff:.3g} Ohm of late back-EMF feed-forward), bandwidth about "
        f"{q.bandwidth_hz:.0f} Hz"
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


def feed_forward_delays(config: ControllerConfig, exchange_period_s: float) -> tuple[float, float]:
    """(D_x, D_v) [s]: how late the controller node's feed-forward shows in the feedback it
    compares with, at the torque boundary (feed_twin/nodeset/reference_delay.py).

    The i_q setpoint computed from the feedback latched at t_k acts from t_{k+1} and is held one
    exchange (its centre 1.5 exchanges late), then the drive's closed current loop lags by about
    2 T_sigma_i = 3 T_i (technical optimum): D_x. The velocity estimate lags the table by the
    estimator's delay on top (half a sample and the FIR's group delay): D_v, the T_sigma the
    velocity loop is re-tuned for (`_retune_velocity`).
    """
    from feed_twin.control.tuning import estimator_delay

    current = config.current
    D_x = 1.5 * exchange_period_s + (3.0 * current.period_s if current is not None else 0.0)
    velocity = config.velocity
    if velocity is None:
        return D_x, D_x
    period = max(velocity.period_s, exchange_period_s)
    est = velocity.estimator
    return D_x, D_x + estimator_delay(est.fir_taps, est.lowpass_hz, period)


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
        self._delayed: DelayedReference | None = None
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
                if (gains or NodeLoopGains()).symmetrize_feed_forward:
                    D_x, D_v = feed_forward_delays(config, exchange_period_s)
                    self._delayed = DelayedReference(
                        period_s=exchange_period_s, position_delay_s=D_x, velocity_delay_s=D_v
                    )
                    self.notes.append(
                        f"feed-forward symmetrized: NC position {D_x * 1e3:.4g} ms and velocity "
                        f"{D_v * 1e3:.4g} ms late, acceleration as it comes"
                    )

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
        for loop in (self._position, self._velocity, self._cascade, self._delayed):
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
        x, v, a = nc.position_m, nc.velocity_m_s, nc.acceleration_m_s2
        if self._delayed is not None:
            x, v, a = self._delayed.update(x, v, a)
        set_nc_reference(ref, x, v, a)
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
