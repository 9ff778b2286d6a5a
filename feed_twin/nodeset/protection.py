"""The drive's axis protection: following-error, current and speed limits as faults.

A real servo drive does not trust its setpoints: it trips when the following error leaves its
window (CiA 402 object 0x6065), when the motor current stays at the current limit longer than
the motor may carry it (the overload, I^2 t in a real drive; here a time at the limit), or when
the speed exceeds the maximum speed (0x6080). Its fault reaction switches the power stage off,
sets the FAULT bit of the status word and reports a fault code; the NC then stops the program.

`DriveProtection` is that monitor, pure and per exchange: `check(t_ns, following_error_m,
i_q_A, velocity_m_s)` returns a `Trip` (fault code, which limit, the value, the limit) the first
time a limit is exceeded and latches it. The sim node applies the fault reaction and ends the
run naming the trip; `describe_trip` adds the program line that was active at the trip's time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from feed_twin.core import signals as sig
from feed_twin.core.validate import require_positive

FAULT_CURRENT_LIMIT = 4  # |i_q| stayed at the current limit for longer than allowed
FAULT_OVERSPEED = 5  # |table velocity| above the speed limit
FAULT_TEXT = {
    sig.FAULT_FOLLOWING_ERROR: "following error",
    sig.FAULT_OVERCURRENT: "phase current above the trip level",
    FAULT_CURRENT_LIMIT: "current at its limit",
    FAULT_OVERSPEED: "speed",
}
# |i_q| at or above this fraction of the limit counts as "at the limit": the measured current
# carries noise and the current loop's ripple around the clipped setpoint.
AT_LIMIT_FRACTION = 0.95
SPEED_LIMIT_FACTOR = 1.2  # default speed limit over the NC's fastest rate of the axis [-]


@dataclass(frozen=True, kw_only=True)
class ProtectionConfig:
    """The `ros.protection` section: which limits trip the drive and when."""

    enabled: bool = True  # false: no monitoring at all (for experiments on an unprotected axis)
    # trip level of |table velocity| [m/s]; None: SPEED_LIMIT_FACTOR x the NC's rapid of the axis
    speed_limit_m_s: float | None = None
    current_limit_time_s: float = 0.5  # [s] time |i_q| may stay at the current limit

    def __post_init__(self) -> None:
        if self.speed_limit_m_s is not None:
            require_positive("speed_limit_m_s", self.speed_limit_m_s)
        require_positive("current_limit_time_s", self.current_limit_time_s)


@dataclass(frozen=True, kw_only=True)
class DriveLimits:
    """The levels the monitor trips at (None: that limit is not monitored)."""

    following_error_m: float | None  # [m]
    current_A: float | None  # the current limit [A] (the controller's effort limit)
    current_time_s: float  # [s] at the current limit before tripping
    speed_m_s: float | None  # [m/s]


@dataclass(frozen=True, kw_only=True)
class Trip:
    t_ns: int  # exchange instant of the trip [ns]
    code: int  # FAULT_* code reported in AxisFeedback.fault_code
    value: float  # the monitored quantity at the trip [m, A or m/s]
    limit: float  # its limit [m, A or m/s]
    source: str  # the config field the limit comes from

    def text(self) -> str:
        t_s = self.t_ns * 1e-9
        if math.isnan(self.value):  # tripped by the drive's own loops, which give no value
            what = f"{FAULT_TEXT.get(self.code, 'fault')} ({self.source})"
        elif self.code == sig.FAULT_FOLLOWING_ERROR:
            what = (
                f"following error {self.value * 1e3:.3f} mm exceeds the limit "
                f"{self.limit * 1e3:.3f} mm ({self.source})"
            )
        elif self.code == FAULT_CURRENT_LIMIT:
            what = (
                f"current {self.value:.2f} A at the limit {self.limit:.2f} A for longer than "
                f"allowed ({self.source})"
            )
        elif self.code == FAULT_OVERSPEED:
            what = (
                f"speed {self.value * 1e3:.1f} mm/s exceeds the limit {self.limit * 1e3:.1f} "
                f"mm/s ({self.source})"
            )
        else:
            what = FAULT_TEXT.get(self.code, f"fault code {self.code}")
        return f"drive fault {self.code} at t = {t_s:.4f} s: {what}"


class DriveProtection:
    """Per-exchange monitor of the drive limits; the first trip latches."""

    def __init__(self, limits: DriveLimits, *, exchange_ns: int) -> None:
        self.limits = limits
        self.exchange_ns = exchange_ns
        self.trip: Trip | None = None
        self._at_limit_ns = 0

    def check(
        self, t_ns: int, following_error_m: float, i_q_A: float, velocity_m_s: float
    ) -> Trip | None:
        """The trip at this exchange, if a limit is exceeded now (None otherwise, and after the
        first trip, which `trip` keeps). A NaN reading trips the limit it belongs to: a drive
        that cannot measure a quantity cannot vouch for it."""
        if self.trip is not None:
            return None
        lim = self.limits
        fe = abs(following_error_m)
        if lim.following_error_m is not None and not fe <= lim.following_error_m:
            return self._latch(
                t_ns, sig.FAULT_FOLLOWING_ERROR, fe, lim.following_error_m,
                "controller.position.following_error_limit_m",
            )  # fmt: skip
        v = abs(velocity_m_s)
        if lim.speed_m_s is not None and not v <= lim.speed_m_s:
            return self._latch(t_ns, FAULT_OVERSPEED, v, lim.speed_m_s, "ros.protection")
        if lim.current_A is not None and not math.isnan(i_q_A):
            if abs(i_q_A) >= AT_LIMIT_FRACTION * lim.current_A:
                self._at_limit_ns += self.exchange_ns
                if self._at_limit_ns > lim.current_time_s * 1e9:
                    return self._latch(
                        t_ns, FAULT_CURRENT_LIMIT, abs(i_q_A), lim.current_A,
                        "controller.drive.effort_limit, ros.protection.current_limit_time_s",
                    )  # fmt: skip
            else:
                self._at_limit_ns = 0
        return None

    def _latch(self, t_ns: int, code: int, value: float, limit: float, source: str) -> Trip:
        self.trip = Trip(t_ns=t_ns, code=code, value=value, limit=limit, source=source)
        return self.trip


def drive_limits(controller, protection: ProtectionConfig, nc_rapid_m_s: float | None):
    """DriveLimits from the controller section (None: no controller), `ros.protection` and the
    NC's fastest rate of the axis; None when protection is off."""
    if not protection.enabled:
        return None
    position = getattr(controller, "position", None)
    drive = getattr(controller, "drive", None)
    speed = protection.speed_limit_m_s
    if speed is None and nc_rapid_m_s is not None:
        speed = SPEED_LIMIT_FACTOR * nc_rapid_m_s
    return DriveLimits(
        following_error_m=None if position is None else position.following_error_limit_m,
        current_A=None if drive is None else drive.effort_limit,
        current_time_s=protection.current_limit_time_s,
        speed_m_s=speed,
    )


def protection_for_config(config_path, ros, exchange_ns: int) -> DriveProtection | None:
    """The drive's limit monitor for an axis config file and its `ros:` section (None:
    `ros.protection.enabled` false)."""
    from feed_twin.sim.config import load_axis_config

    axis = load_axis_config(config_path)
    rapid = None
    if axis.nc is not None:
        from feed_twin.gcode.config import nc_config_from_mapping

        nc = nc_config_from_mapping(axis.nc, source=str(config_path))
        spec = next(a for a in nc.axes if a.name == nc.twin_axis)
        rapid = max(spec.rapid_m_s, spec.v_max_m_s)
    limits = drive_limits(axis.controller, ros.protection, rapid)
    return None if limits is None else DriveProtection(limits, exchange_ns=exchange_ns)


def line_at(t_s: float, command_t_s, command_line) -> int | None:
    """The program line of the last NC setpoint at or before t_s (None: none yet)."""
    k = int(np.searchsorted(np.asarray(command_t_s), t_s + 1e-12, side="right")) - 1
    if k < 0:
        return None
    line = int(command_line[k])
    return line if line >= 1 else None


def describe_trip(reason: str, run: dict | None, command_topic: str, lines: dict | None) -> str:
    """`reason` with the program line active at the drive fault's time, when it names one."""
    marker = "drive fault "
    if run is None or marker not in reason or " at t = " not in reason:
        return reason
    try:
        t_s = float(reason.split(" at t = ", 1)[1].split(" s", 1)[0])
    except (IndexError, ValueError):
        return reason
    command = run.get(command_topic)
    if command is None or len(command.get("line", ())) == 0:
        return reason
    line = line_at(t_s, command["header.stamp"], command["line"])
    if line is None:
        return reason
    text = (lines or {}).get(line, "").strip()
    return f"{reason} (program line {line}{': ' + text if text else ''})"
