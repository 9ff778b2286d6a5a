"""Signal layouts at the controller/drive boundary, shared by the controller and the engine.

The compiled loop passes three flat float64 vectors between the plant and the controller once
per base tick. Their slots are named here and nowhere else; numba reads these module constants
as compile-time integers, so the kernels index by name without a cost.

All positions and velocities on this boundary are load side (table) in SI units, as the NC
produces them; the controller converts to motor side with its own copy of the screw lead.
"""

from __future__ import annotations

# Reference: what arrives from upstream (NC setpoints, or an external loop in CSV/CST modes).
REF_POS_M = 0  # NC position setpoint of the table [m], held between NC samples
REF_VEL_M_S = 1  # NC velocity setpoint [m/s] (velocity feed-forward)
REF_ACC_M_S2 = 2  # NC acceleration setpoint [m/s^2] (acceleration feed-forward)
REF_VEL_EXT_M_S = 3  # external velocity setpoint [m/s] when the position loop runs elsewhere
REF_I_Q_EXT_A = 4  # external q-current (torque) setpoint [A] when only the current loop runs here
REF_EFFORT_ADD = 5  # known signal added to the controller's effort output (drive input units)
REF_SIZE = 6
REF_NAMES = (
    "pos_ref_m",
    "vel_ref_m_s",
    "acc_ref_m_s2",
    "vel_ext_m_s",
    "i_q_ext_A",
    "effort_add",
)

# Measurement: what the sensors deliver to the controller at a sample instant.
MEAS_THETA_ENC_RAD = 0  # motor encoder angle, mechanical [rad], quantised and delayed
MEAS_X_SCALE_M = 1  # linear scale position of the table [m], quantised and delayed
MEAS_I_A = 2  # measured phase currents [A]
MEAS_I_B = 3
MEAS_I_C = 4
MEAS_U_DC_V = 5  # measured DC-bus voltage [V]
MEAS_SIZE = 6
MEAS_NAMES = ("theta_enc_rad", "x_scale_m", "i_a_meas_A", "i_b_meas_A", "i_c_meas_A", "u_dc_V")

# Output: what the controller commands, plus internals worth recording.
OUT_DUTY_A = 0  # inverter duty cycles in [0, 1], applied by the plant's inverter
OUT_DUTY_B = 1
OUT_DUTY_C = 2
OUT_EFFORT_CMD = 3  # command to an ideal torque/force source, in the drive's input units
OUT_I_D_REF_A = 4
OUT_I_Q_REF_A = 5
OUT_U_D_REF_V = 6
OUT_U_Q_REF_V = 7
OUT_POS_REF_M = 8  # fine-interpolated position setpoint [m]
OUT_VEL_REF_M_S = 9  # velocity-loop setpoint [m/s], load side
OUT_VEL_EST_M_S = 10  # velocity estimate used by the velocity loop [m/s], load side
OUT_FOLLOWING_ERROR_M = 11  # position setpoint minus measured position [m]
OUT_FAULT = 12  # 0 = none, else a FAULT_* code; the drive disables itself
OUT_ENABLED = 13  # 1.0 when the power stage is enabled
OUT_SIZE = 14
OUT_NAMES = (
    "duty_a",
    "duty_b",
    "duty_c",
    "effort_cmd",
    "i_d_ref_A",
    "i_q_ref_A",
    "u_d_ref_V",
    "u_q_ref_V",
    "pos_ref_m",
    "vel_ref_m_s",
    "vel_est_m_s",
    "following_error_m",
    "fault",
    "enabled",
)

FAULT_NONE = 0
FAULT_FOLLOWING_ERROR = 1  # |following error| exceeded its limit
FAULT_OVERCURRENT = 2  # a measured phase current exceeded the trip level
FAULT_DISABLED = 3  # the drive was disabled by command
FAULT_REASONS = {
    FAULT_NONE: "none",
    FAULT_FOLLOWING_ERROR: "following error limit exceeded",
    FAULT_OVERCURRENT: "phase current above trip level",
    FAULT_DISABLED: "disabled by command",
}

assert len(REF_NAMES) == REF_SIZE and len(MEAS_NAMES) == MEAS_SIZE and len(OUT_NAMES) == OUT_SIZE
