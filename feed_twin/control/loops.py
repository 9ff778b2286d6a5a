"""The cascade in the ros2_control shape: `reset()`, then `update(t, reference, measurement)`.

These classes are for use outside the compiled engine (the ROS controller node, notebooks, tests).
They hold a parameter and a state vector from `build_cascade` and call the engine's own njit
`cascade_tick` with the loops they do not own switched off, so there is one implementation of
every control law.

Each controller runs at a fixed sample period: `update` must be called at `t = k * period_s` on the
base grid (a multiple of the loop's own period), with strictly increasing k, otherwise it raises.
`measurement` is always a MEAS_* vector; `reference` and the command depend on the loop:

| class          | reference                          | command                                  |
|----------------|------------------------------------|------------------------------------------|
| `Cascade`      | REF_* vector                       | OUT_* vector (copy)                      |
| `PositionLoop` | REF_* vector (NC x, v, a)          | `PositionCommand` (v_ref, effort_ff, ...) |
| `VelocityLoop` | `VelocitySetpoint` (v, effort_ff)  | effort / q-current setpoint [A or unit]  |
| `CurrentLoop`  | q-current setpoint [A]             | duty cycles (a, b, c) in [0, 1]          |
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from feed_twin.control import cascade as cc
from feed_twin.control import layout as lay
from feed_twin.control.config import ControllerConfig, Mode
from feed_twin.core import signals as sig


@dataclass(frozen=True, kw_only=True)
class PositionCommand:
    vel_ref_m_s: float  # velocity setpoint for the velocity loop [m/s], load side
    effort_ff: float  # acceleration feed-forward [effort unit, A for a PMSM]
    pos_ref_m: float  # fine-interpolated position setpoint [m]
    following_error_m: float  # setpoint minus feedback position [m]


@dataclass(frozen=True, kw_only=True)
class VelocitySetpoint:
    vel_m_s: float  # [m/s], load side
    effort_ff: float = 0.0  # feed-forward added to the loop output [effort unit]


class _SampledController:
    """Fixed-period bookkeeping shared by the loop classes: time -> tick, reset, state vector.

    A loop class runs `cascade_tick` on a copy of the parameter vector in which the loops it does
    not own are switched off (and the computation delay, which belongs to the drive's output,
    is off unless the class owns the innermost loop).
    """

    def __init__(
        self,
        config: ControllerConfig,
        loop_period_s: float,
        *,
        mode: Mode,
        keep: tuple[str, ...],
        computation_delay: bool = False,
    ) -> None:
        self._cascade = lay.build_cascade(
            dataclasses.replace(config, mode=mode, computation_delay=computation_delay)
        )
        params = self._cascade.params.copy()
        for loop, slot in (
            ("position", lay.P_HAS_POSITION),
            ("velocity", lay.P_HAS_VELOCITY),
            ("current", lay.P_HAS_CURRENT),
        ):
            if loop not in keep:
                params[slot] = lay.LOOP_ABSENT
        params.setflags(write=False)
        self._params = params
        self.base_period_s = self._cascade.base_period_s
        self.period_s = loop_period_s
        self._div = round(loop_period_s / self.base_period_s)
        self._ref = np.zeros(sig.REF_SIZE)
        self._out = np.zeros(sig.OUT_SIZE)
        self.reset()

    @property
    def params(self) -> np.ndarray:
        return self._params

    @property
    def state(self) -> dict[str, float]:
        """Named copy of the controller state (integrators, filters, fault, ...)."""
        return self._cascade.state_view(self._cs)

    @property
    def fault(self) -> int:
        """Latched FAULT_* code, 0 when none."""
        return int(self._cs[lay.S_FAULT])

    def reset(self) -> None:
        """Back to the initial state; the next update may start at any grid time."""
        self._cs = self._cascade.initial_state()
        self._last_k: int | None = None

    def enable(self) -> None:
        lay.enable(self._cs)

    def disable(self) -> None:
        lay.disable(self._cs)

    def clear_fault(self) -> None:
        lay.clear_fault(self._cs)

    def _step(self, t: float, ref: np.ndarray, measurement: np.ndarray) -> np.ndarray:
        meas = self._vector("measurement", measurement, sig.MEAS_SIZE)
        k = round(t / self.base_period_s)
        if abs(t - k * self.base_period_s) > 1e-6 * self.base_period_s or k % self._div:
            raise ValueError(
                f"t = {t!r} s: not a sample instant of this loop (period {self.period_s!r} s)"
            )
        if self._last_k is not None and k <= self._last_k:
            raise ValueError(
                f"t = {t!r} s: not after the previous update at "
                f"{self._last_k * self.base_period_s!r} s"
            )
        self._last_k = k
        cc.cascade_tick(self._params, self._cs, k, ref, meas, self._out)
        return self._out

    @staticmethod
    def _vector(name: str, value: np.ndarray, size: int) -> np.ndarray:
        arr = np.ascontiguousarray(value, dtype=np.float64)
        if arr.shape != (size,):
            raise ValueError(f"{name}: expected a vector of {size} floats, got shape {arr.shape}")
        return arr


class Cascade(_SampledController):
    """All configured loops at the base period in the configured mode: the engine's tick."""

    def __init__(self, config: ControllerConfig) -> None:
        super().__init__(
            config,
            config.base_period_s,
            mode=config.mode,
            keep=("position", "velocity", "current"),
            computation_delay=config.computation_delay,
        )

    def update(self, t: float, reference: np.ndarray, measurement: np.ndarray) -> np.ndarray:
        ref = self._vector("reference", reference, sig.REF_SIZE)
        return self._step(t, ref, measurement).copy()


class PositionLoop(_SampledController):
    """P position loop with velocity/acceleration feed-forward and fine interpolation; trips on
    the following-error limit (see `fault`)."""

    def __init__(self, config: ControllerConfig) -> None:
        if config.position is None:
            raise ValueError("PositionLoop: the configuration has no position section")
        super().__init__(config, config.position.period_s, mode="position", keep=("position",))

    def update(self, t: float, reference: np.ndarray, measurement: np.ndarray) -> PositionCommand:
        ref = self._vector("reference", reference, sig.REF_SIZE)
        out = self._step(t, ref, measurement)
        return PositionCommand(
            vel_ref_m_s=float(out[sig.OUT_VEL_REF_M_S]),
            effort_ff=float(self._cs[lay.S_EFFORT_FF]),
            pos_ref_m=float(out[sig.OUT_POS_REF_M]),
            following_error_m=float(out[sig.OUT_FOLLOWING_ERROR_M]),
        )


class VelocityLoop(_SampledController):
    """PI velocity loop on the encoder-difference estimate, with limit and setpoint filters."""

    def __init__(self, config: ControllerConfig) -> None:
        if config.velocity is None:
            raise ValueError("VelocityLoop: the configuration has no velocity section")
        super().__init__(config, config.velocity.period_s, mode="velocity", keep=("velocity",))

    def update(self, t: float, reference: VelocitySetpoint, measurement: np.ndarray) -> float:
        self._ref[sig.REF_VEL_EXT_M_S] = reference.vel_m_s
        self._ref[sig.REF_EFFORT_ADD] = reference.effort_ff
        return float(self._step(t, self._ref, measurement)[sig.OUT_EFFORT_CMD])

    @property
    def velocity_estimate_m_s(self) -> float:
        return float(self._cs[lay.S_VEL_EST])


class CurrentLoop(_SampledController):
    """FOC current loop: d/q PI, decoupling, voltage limit, SVPWM, computation delay.

    The speed for decoupling and back-EMF feed-forward comes from `set_velocity_estimate`
    (load side m/s), normally the velocity loop's estimate.
    """

    def __init__(self, config: ControllerConfig) -> None:
        if config.current is None:
            raise ValueError("CurrentLoop: the configuration has no current section")
        super().__init__(
            config,
            config.current.period_s,
            mode="torque",
            keep=("current",),
            computation_delay=config.computation_delay,
        )

    def set_velocity_estimate(self, vel_m_s: float) -> None:
        self._cs[lay.S_VEL_EST] = vel_m_s

    def update(
        self, t: float, reference: float, measurement: np.ndarray
    ) -> tuple[float, float, float]:
        self._ref[sig.REF_I_Q_EXT_A] = reference
        out = self._step(t, self._ref, measurement)
        return (
            float(out[sig.OUT_DUTY_A]),
            float(out[sig.OUT_DUTY_B]),
            float(out[sig.OUT_DUTY_C]),
        )
