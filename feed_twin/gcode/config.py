"""NC configuration: the machine's axes, limits, work offsets and planner tolerances.

`NcConfig` is read from the `nc:` section of an axis or machine config YAML (other top-level
sections are ignored). Linear values are SI; millimetres appear only in G-code text. Rotary axes
(A, B, C) are configured in degrees, as their G-code words are, and held in radians inside: the
planned vector of a machine with rotary axes mixes metres and radians (linear axes first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_finite, require_nonnegative, require_positive

LINEAR_AXIS_NAMES = ("X", "Y", "Z", "U", "V", "W")
ROTARY_AXIS_NAMES = ("A", "B", "C")
WORK_OFFSET_CODES = ("G54", "G55", "G56", "G57", "G58", "G59")


@dataclass(frozen=True, kw_only=True)
class NcAxis:
    """One linear machine axis and its kinematic limits (machine coordinates)."""

    name: str  # G-code letter: X, Y, Z, U, V or W
    v_max_m_s: float  # [m/s] largest velocity of feed moves
    rapid_m_s: float  # [m/s] rapid traverse rate (G0)
    a_max_m_s2: float  # [m/s^2] acceleration limit
    j_max_m_s3: float  # [m/s^3] jerk limit (used by the 'jerk' profile)
    travel_min_m: float  # [m] lower software limit
    travel_max_m: float  # [m] upper software limit

    def __post_init__(self) -> None:
        if self.name not in LINEAR_AXIS_NAMES:
            raise ValueError(f"name = {self.name!r}: must be one of {', '.join(LINEAR_AXIS_NAMES)}")
        for name in ("v_max_m_s", "rapid_m_s", "a_max_m_s2", "j_max_m_s3"):
            require_positive(name, getattr(self, name))
        if not (math.isfinite(self.travel_min_m) and math.isfinite(self.travel_max_m)):
            raise ValueError(
                f"travel_min_m, travel_max_m = {self.travel_min_m!r}, {self.travel_max_m!r}: "
                "must be finite"
            )
        if self.travel_max_m <= self.travel_min_m:
            raise ValueError(
                f"travel_max_m = {self.travel_max_m!r}: must be > travel_min_m = "
                f"{self.travel_min_m!r}"
            )


@dataclass(frozen=True, kw_only=True)
class NcRotaryAxis:
    """One rotary axis (degrees at this edge, radians inside; see `NcConfig.v_max` etc.)."""

    name: str  # G-code letter: A, B or C
    v_max_deg_s: float  # [deg/s] largest angular velocity of feed moves
    rapid_deg_s: float  # [deg/s] rapid rate (G0)
    a_max_deg_s2: float  # [deg/s^2] angular acceleration limit
    j_max_deg_s3: float  # [deg/s^3] angular jerk limit
    travel_min_deg: float  # [deg] lower software limit
    travel_max_deg: float  # [deg] upper software limit
    start_deg: float = 0.0  # [deg] position when the program starts

    def __post_init__(self) -> None:
        if self.name not in ROTARY_AXIS_NAMES:
            raise ValueError(f"name = {self.name!r}: must be one of {', '.join(ROTARY_AXIS_NAMES)}")
        for name in ("v_max_deg_s", "rapid_deg_s", "a_max_deg_s2", "j_max_deg_s3"):
            require_positive(name, getattr(self, name))
        for name in ("travel_min_deg", "travel_max_deg", "start_deg"):
            require_finite(name, getattr(self, name))
        if self.travel_max_deg <= self.travel_min_deg:
            raise ValueError(
                f"travel_max_deg = {self.travel_max_deg!r}: must be > travel_min_deg = "
                f"{self.travel_min_deg!r}"
            )
        if not self.travel_min_deg <= self.start_deg <= self.travel_max_deg:
            raise ValueError(
                f"start_deg = {self.start_deg!r}: outside the travel "
                f"[{self.travel_min_deg}, {self.travel_max_deg}]"
            )


@dataclass(frozen=True, kw_only=True)
class WorkOffsets:
    """Work coordinate origins G54-G59 in machine coordinates [m], one entry per linear axis
    (rotary axes have none: their program angle is the machine angle)."""

    G54: tuple[float, ...]
    G55: tuple[float, ...]
    G56: tuple[float, ...]
    G57: tuple[float, ...]
    G58: tuple[float, ...]
    G59: tuple[float, ...]


@dataclass(frozen=True, kw_only=True)
class NcConfig:
    """Everything the interpreter and planner need to turn a program into setpoints.

    `exact_stop_settle_s` is the NC's wait for the in-position window at each exact stop,
    modelled as a fixed dwell (the real wait ends when the following error is small enough).
    """

    axes: tuple[NcAxis, ...]  # the machine's linear axes; X, Y and Z are required
    # the axis a single-axis twin models (the others are still planned); a machine config
    # (feed_twin.machine) simulates several and leaves this at its first simulated axis
    twin_axis: str = "X"
    work_offsets_m: WorkOffsets  # [m] G54-G59 origins
    start_position_m: tuple[float, ...]  # [m] machine position when the program starts
    path_tolerance_m: float  # [m] G64 corner blending: largest deviation from the corner
    chord_tolerance_m: float  # [m] largest sagitta of the chords that approximate an arc
    arc_radius_tolerance_m: float  # [m] allowed start/end radius mismatch of an arc
    interpolation_period_s: float = 1e-3  # [s] setpoint sample period
    profile: Literal["jerk", "trapezoid"] = "jerk"  # jerk-limited S-curve or trapezoidal
    lookahead_segments: int = 2000  # segments planned together when streaming
    block_delete: bool = True  # '/' blocks are skipped (the block-delete switch is on)
    dwell_p_unit: Literal["s", "ms"] = "s"  # unit of G4 P (RS274/NGC: s; Fanuc: ms)
    # [s] hold at rest after each block that ends in an exact stop (G60, G61, G61.1, G9)
    # before the next block starts. A real NC waits until the axes are inside the in-position
    # window (Sinumerik G601/G602), which depends on the drive; this models that wait as a
    # fixed time (tens of ms on a machining centre).
    exact_stop_settle_s: float = 0.0
    rotary_axes: tuple[NcRotaryAxis, ...] = ()  # A, B, C, planned after the linear axes
    axis_names: tuple[str, ...] = field(init=False)  # linear axes, then rotary axes
    # Per planned axis, SI (m or rad): limits and the position when a program starts.
    v_max: tuple[float, ...] = field(init=False)
    rapid: tuple[float, ...] = field(init=False)
    a_max: tuple[float, ...] = field(init=False)
    j_max: tuple[float, ...] = field(init=False)
    travel: tuple[tuple[float, float], ...] = field(init=False)
    start_position: tuple[float, ...] = field(init=False)

    def __post_init__(self) -> None:
        names = tuple(a.name for a in self.axes)
        rotary = tuple(a.name for a in self.rotary_axes)
        if len(set(rotary)) != len(rotary):
            raise ValueError(f"rotary_axes = {rotary!r}: axis names must be unique")
        if len(set(names)) != len(names):
            raise ValueError(f"axes = {names!r}: axis names must be unique")
        for required in ("X", "Y", "Z"):
            if required not in names:
                raise ValueError(f"axes = {names!r}: axis {required} is required")
        if self.twin_axis not in names:
            raise ValueError(f"twin_axis = {self.twin_axis!r}: must be one of {names!r}")
        n = len(names)
        if len(self.start_position_m) != n:
            raise ValueError(
                f"start_position_m = {self.start_position_m!r}: needs {n} entries (one per axis)"
            )
        for i, (axis, x) in enumerate(zip(self.axes, self.start_position_m, strict=True)):
            if not axis.travel_min_m <= x <= axis.travel_max_m:
                raise ValueError(
                    f"start_position_m[{i}] = {x!r}: outside the travel of axis {axis.name} "
                    f"[{axis.travel_min_m}, {axis.travel_max_m}]"
                )
        for code in WORK_OFFSET_CODES:
            offset = getattr(self.work_offsets_m, code)
            if len(offset) != n:
                raise ValueError(
                    f"work_offsets_m.{code} = {offset!r}: needs {n} entries (one per axis)"
                )
        require_positive("path_tolerance_m", self.path_tolerance_m)
        require_positive("chord_tolerance_m", self.chord_tolerance_m)
        require_nonnegative("arc_radius_tolerance_m", self.arc_radius_tolerance_m)
        require_positive("interpolation_period_s", self.interpolation_period_s)
        require_nonnegative("exact_stop_settle_s", self.exact_stop_settle_s)
        # YAML may give a float or a bool where the annotation says int
        lookahead = self.lookahead_segments
        if isinstance(lookahead, bool) or not isinstance(lookahead, int):  # pyright: ignore[reportUnnecessaryIsInstance]
            raise ValueError(f"lookahead_segments = {self.lookahead_segments!r}: must be an int")
        if self.lookahead_segments < 8:
            raise ValueError(f"lookahead_segments = {self.lookahead_segments!r}: must be >= 8")
        deg = math.pi / 180.0
        lin, rot = self.axes, self.rotary_axes
        derived = {
            "axis_names": names + rotary,
            "v_max": tuple(a.v_max_m_s for a in lin) + tuple(a.v_max_deg_s * deg for a in rot),
            "rapid": tuple(a.rapid_m_s for a in lin) + tuple(a.rapid_deg_s * deg for a in rot),
            "a_max": tuple(a.a_max_m_s2 for a in lin) + tuple(a.a_max_deg_s2 * deg for a in rot),
            "j_max": tuple(a.j_max_m_s3 for a in lin) + tuple(a.j_max_deg_s3 * deg for a in rot),
            "travel": tuple((a.travel_min_m, a.travel_max_m) for a in lin)
            + tuple((a.travel_min_deg * deg, a.travel_max_deg * deg) for a in rot),
            "start_position": tuple(self.start_position_m) + tuple(a.start_deg * deg for a in rot),
        }
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    def axis_kind(self, name: str) -> Literal["linear", "rotary"]:
        return "rotary" if name in ROTARY_AXIS_NAMES else "linear"

    def axis_index(self, name: str) -> int:
        return self.axis_names.index(name)

    @property
    def twin_start_position_m(self) -> float:
        """Machine position of the twin axis when a program starts [m]."""
        return self.start_position_m[self.axis_index(self.twin_axis)]


def nc_config_from_mapping(data: object, *, source: str) -> NcConfig:
    """Build an `NcConfig` from the mapping under `nc:`; errors read `source: nc.field ...`."""
    return from_mapping(NcConfig, data, source=source, path="nc")


def load_nc_config(path: str | Path) -> NcConfig:
    """Read the `nc:` section of any YAML file (other top-level sections are ignored)."""
    data = load_yaml(path)
    if "nc" not in data:
        raise ConfigError(f"{path}: no 'nc' section (top-level keys: {', '.join(map(str, data))})")
    return nc_config_from_mapping(data["nc"], source=str(path))
