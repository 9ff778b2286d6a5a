"""Column maps: how a measured file's own columns and units become feed_twin's canonical signals.

A column map (YAML, read by `load_column_map`) names the time column (or, for a log without
one, the rate its rows were written at: `time: {index: true, rate_hz: 10}`) and, for each canonical
signal, the file's column, its unit and how to turn it into SI: `(reading - offset) * unit
factor * gain` (a negative gain flips a sign; a current mapped to a force or torque needs its
constant as gain; `amplitude: rms` turns an RMS current into the peak), motor angles and encoder
counts through the lead, plus what the axis can do (`plausibility`) and how the recorder made
a sample (`trace_filter`, `effort_sample`). feed_twin.io.measured applies it to a file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_positive

Dimension = Literal["time", "length", "velocity", "force", "torque", "current", "voltage"]

# unit -> (dimension, factor to SI). Angles and counts are handled separately through the lead.
_UNITS: dict[str, tuple[str, float]] = {
    "s": ("time", 1.0),
    "ms": ("time", 1e-3),
    "us": ("time", 1e-6),
    "m": ("length", 1.0),
    "mm": ("length", 1e-3),
    "um": ("length", 1e-6),
    "m/s": ("velocity", 1.0),
    "mm/s": ("velocity", 1e-3),
    "mm/min": ("velocity", 1e-3 / 60.0),
    "m/min": ("velocity", 1.0 / 60.0),
    "N": ("force", 1.0),
    "kN": ("force", 1e3),
    "Nm": ("torque", 1.0),
    "mNm": ("torque", 1e-3),
    "A": ("current", 1.0),
    "mA": ("current", 1e-3),
    "V": ("voltage", 1.0),
    # motor-side angles, converted to table travel through the lead
    "rad": ("angle", 1.0),
    "deg": ("angle", math.pi / 180.0),
    "rev": ("angle", 2.0 * math.pi),
    "counts": ("angle", math.nan),  # 2*pi / counts_per_rev, known only from the map
    "rad/s": ("angular_velocity", 1.0),
    "rpm": ("angular_velocity", 2.0 * math.pi / 60.0),
}
UNITS = tuple(_UNITS)

_CANONICAL_DIMENSION: dict[str, str] = {
    "pos_cmd_m": "length",
    "vel_cmd_m_s": "velocity",
    "pos_meas_m": "length",
    "vel_meas_m_s": "velocity",
    "force_cmd_N": "force",
    "torque_cmd_Nm": "torque",
    "current_q_A": "current",
    "current_d_A": "current",
    "voltage_d_V": "voltage",
    "voltage_q_V": "voltage",
}
_DISTURBANCE_SUFFIX = {"_N": "force", "_Nm": "torque", "_A": "current"}
EFFORT_SIGNALS = ("force_cmd_N", "torque_cmd_Nm", "current_q_A")
EFFORT_UNITS = {"force_cmd_N": "N", "torque_cmd_Nm": "N m", "current_q_A": "A"}
VOLTAGE_SIGNALS = ("voltage_d_V", "voltage_q_V")  # the current controller's voltage commands
EFFORT_SAMPLES = ("actual", "setpoint")  # ColumnMap.effort_sample


def canonical_dimension(name: str) -> str:
    """The physical dimension a canonical signal carries, or raise naming the allowed names."""
    if name in _CANONICAL_DIMENSION:
        return _CANONICAL_DIMENSION[name]
    if name.startswith("disturbance_"):
        for suffix in ("_Nm", "_N", "_A"):
            if name.endswith(suffix) and len(name) > len("disturbance_") + len(suffix):
                return _DISTURBANCE_SUFFIX[suffix]
    allowed = ", ".join(_CANONICAL_DIMENSION)
    raise ValueError(
        f"{name!r} is not a canonical signal; use one of {allowed} or disturbance_<what>_<N|Nm|A>"
    )


@dataclass(frozen=True, kw_only=True)
class ColumnSpec:
    """Where one canonical signal comes from in the file."""

    column: str  # the file's own column name (CSV header) or topic field path (bag)
    unit: str  # one of UNITS
    # [target SI unit per column unit]: the drive gain of a column in V mapped to an effort, the
    # force (torque) constant [N/A, N m/A] of a current mapped to a force (torque), else a scale;
    # negative where the machine counts the other way (a current whose sign opposes the motion)
    gain: float | None = None
    offset: float = 0.0  # [column unit] the reading at zero, subtracted first
    # a current column as the drive shows it: "peak" phase current (the q-current of an
    # amplitude-invariant transform) or its "rms" (sqrt(2) times smaller)
    amplitude: Literal["peak", "rms"] = "peak"
    optional: bool = False  # a missing column is skipped instead of an error

    def __post_init__(self) -> None:
        if self.unit not in _UNITS:
            raise ValueError(f"unit = {self.unit!r}: must be one of {', '.join(UNITS)}")
        if self.gain is not None and not (math.isfinite(self.gain) and self.gain != 0.0):
            raise ValueError(f"gain = {self.gain!r}: must be a finite number other than 0")
        if not math.isfinite(self.offset):
            raise ValueError(f"offset = {self.offset!r}: must be finite")
        if self.amplitude not in ("peak", "rms"):
            raise ValueError(f"amplitude = {self.amplitude!r}: must be 'peak' or 'rms'")
        if self.amplitude == "rms" and _UNITS[self.unit][0] != "current":
            raise ValueError(
                f"amplitude = 'rms' with unit = {self.unit!r}: only a current has an RMS reading"
            )

    def to_si(self, raw: np.ndarray) -> np.ndarray:
        """The column in SI for a dimension that needs no machine data (not angles)."""
        factor = _UNITS[self.unit][1] * (1.0 if self.gain is None else self.gain)
        if self.amplitude == "rms":
            factor *= math.sqrt(2.0)
        return (raw - self.offset) * factor


@dataclass(frozen=True, kw_only=True)
class RowTime:
    """Time from the row index, t = row / rate_hz [s]: a monitoring log (MTConnect, OPC UA)
    written at a fixed rate without a time column."""

    index: bool  # must be true: the rows' order is their time
    rate_hz: float  # [Hz] rows per second

    def __post_init__(self) -> None:
        if self.index is not True:
            raise ValueError(
                f"index = {self.index!r}: time from the row index needs index: true (or give "
                "time: {column: ..., unit: ...})"
            )
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0.0):
            raise ValueError(f"rate_hz = {self.rate_hz!r}: must be a positive number of rows/s")


TimeSpec = ColumnSpec | RowTime


@dataclass(frozen=True, kw_only=True)
class Conversion:
    """Machine data needed to turn motor angles and encoder counts into table travel."""

    lead_m: float | None = None  # [m/rev] screw lead
    counts_per_rev: float | None = None  # [1] encoder counts per motor revolution

    def __post_init__(self) -> None:
        if self.lead_m is not None:
            require_positive("lead_m", self.lead_m)
        if self.counts_per_rev is not None:
            require_positive("counts_per_rev", self.counts_per_rev)


@dataclass(frozen=True, kw_only=True)
class Plausibility:
    """What the axis can physically do; used to catch unit mistakes such as mm declared as m."""

    travel_m: float  # [m] longest stroke of the axis
    max_speed_m_s: float  # [m/s] fastest speed the axis can reach

    def __post_init__(self) -> None:
        require_positive("travel_m", self.travel_m)
        require_positive("max_speed_m_s", self.max_speed_m_s)


@dataclass(frozen=True, kw_only=True)
class _MapFile:
    position_sensor: Literal["motor_encoder", "linear_scale"]
    signals: Any  # name -> ColumnSpec mapping, parsed by load_column_map
    plausibility: Plausibility
    time: Any = None  # a ColumnSpec or a RowTime mapping; None: the rate comes from --rate
    conversion: Conversion = field(default_factory=Conversion)
    trace_filter: Literal["none", "mean"] = "none"
    effort_sample: Literal["actual", "setpoint"] = "actual"


@dataclass(frozen=True, kw_only=True)
class ColumnMap:
    """A parsed column map: the time column (or the row rate), the mapped signals, and the
    machine data. `time` None: the map leaves the rate to the command line (--rate)."""

    time: TimeSpec | None
    position_sensor: Literal["motor_encoder", "linear_scale"]
    signals: tuple[tuple[str, ColumnSpec], ...]
    plausibility: Plausibility
    conversion: Conversion
    source: str = "<map>"
    # how the recorder made a sample: "none", the signal at the stamp; "mean", its mean over the
    # sample period ending at the stamp (a drive's trace of a faster loop)
    trace_filter: Literal["none", "mean"] = "none"
    # what the effort column holds at a stamp: "actual", the effort that acted up to it (a
    # measured current or force, sampled before the drive applies the command of that tick);
    # "setpoint", the command the controller issued at it (EMPS's control voltage)
    effort_sample: Literal["actual", "setpoint"] = "actual"

    def __post_init__(self) -> None:
        if self.effort_sample not in EFFORT_SAMPLES:
            raise ValueError(
                f"effort_sample = {self.effort_sample!r}: must be one of "
                f"{', '.join(EFFORT_SAMPLES)}"
            )
        for name, spec in self.signals:
            _check_convertible(name, spec, self.conversion)


def _check_convertible(name: str, spec: ColumnSpec, conv: Conversion) -> None:
    target = canonical_dimension(name)
    dim = _UNITS[spec.unit][0]
    if dim == target:
        return
    if dim == "voltage" and target in ("force", "torque", "current"):
        if spec.gain is None:
            raise ValueError(
                f"signals.{name}.gain = None: a column in V needs the drive gain (e.g. N/V) "
                f"to give {name}"
            )
        return
    if dim == "current" and target in ("force", "torque"):
        if spec.gain is None:
            raise ValueError(
                f"signals.{name}.gain = None: a current gives {name} only through the drive's "
                f"{'force constant [N/A]' if target == 'force' else 'torque constant [N m/A]'}"
            )
        return
    if dim == "angle" and target == "length" or dim == "angular_velocity" and target == "velocity":
        if conv.lead_m is None:
            raise ValueError(
                f"signals.{name}.unit = {spec.unit!r}: converting a motor angle to table travel "
                "needs conversion.lead_m"
            )
        if spec.unit == "counts" and conv.counts_per_rev is None:
            raise ValueError(f"signals.{name}.unit = 'counts': needs conversion.counts_per_rev")
        return
    raise ValueError(
        f"signals.{name}.unit = {spec.unit!r}: a {dim} unit cannot give {name}, which is a {target}"
    )


def load_column_map(path: str | Path) -> ColumnMap:
    """Read a column-map YAML; errors read `file: field = value: reason`."""
    source = str(path)
    data = load_yaml(path)
    raw = from_mapping(_MapFile, data, source=source)
    if not isinstance(raw.signals, dict) or not raw.signals:
        raise ConfigError(f"{source}: signals = {raw.signals!r}: expected a non-empty mapping")
    signals = []
    for name, spec in raw.signals.items():
        try:
            canonical_dimension(str(name))
        except ValueError as exc:
            raise ConfigError(f"{source}: signals.{name}: {exc}") from None
        signals.append(
            (str(name), from_mapping(ColumnSpec, spec, source=source, path=f"signals.{name}"))
        )
    time = _time_spec(raw.time, source)
    try:
        return ColumnMap(
            time=time,
            position_sensor=raw.position_sensor,
            signals=tuple(signals),
            plausibility=raw.plausibility,
            conversion=raw.conversion,
            source=source,
            trace_filter=raw.trace_filter,
            effort_sample=raw.effort_sample,
        )
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def _time_spec(data: Any, source: str) -> TimeSpec | None:
    """The map's `time:`: a column (`{column, unit[, gain]}`), the row index at a rate
    (`{index: true, rate_hz}`), or nothing (the rate is given on the command line)."""
    if data is None:
        return None
    if isinstance(data, dict) and "index" in data:
        return from_mapping(RowTime, data, source=source, path="time")
    spec = from_mapping(ColumnSpec, data, source=source, path="time")
    if _UNITS[spec.unit][0] != "time":
        raise ConfigError(f"{source}: time.unit = {spec.unit!r}: must be a time unit")
    if spec.gain is not None and spec.gain < 0.0:
        raise ConfigError(f"{source}: time.gain = {spec.gain!r}: must be > 0 (time runs forwards)")
    return spec
