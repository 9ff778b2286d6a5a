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

The messages' plain forms (`NcSample`, `DriveSetpoint`), the CiA 402 modes and `drive_reference`,
which fills the simulated drive's reference from a setpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feed_twin.core import signals as sig
from feed_twin.sim.program import set_nc_reference

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
