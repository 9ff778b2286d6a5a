"""Measured runs of a real (or simulated) axis, mapped onto feed_twin's canonical signals.

A measured file (CSV, or a rosbag2 recording when `feed_twin.io.bag` is available) carries its
own column names and units. A small YAML column map ties them to the canonical signals

    t_s, pos_cmd_m, vel_cmd_m_s, pos_meas_m, vel_meas_m_s, force_cmd_N, torque_cmd_Nm,
    current_q_A, current_d_A, voltage_d_V, voltage_q_V, disturbance_<what>_<N|Nm|A>

(`voltage_d_V`/`voltage_q_V`: the d/q voltages the drive's current controller commands, as
drive scopes record them; a column in V mapped to an effort needs the drive gain, one mapped to
a voltage does not)

and every unit conversion (mm, mm/min, degrees, encoder counts, volts with a drive gain) happens
once, here, at the edge. Everything downstream works in SI.

Validation follows one rule: a problem the user must fix raises `MeasuredDataError` naming the
column and the problem; a problem with a documented repair is repaired and reported in
`MeasuredRun.warnings` with the number of samples touched:
- NaN or empty cells inside a column are linearly interpolated in time (edges held);
- gaps in the time stamps (a step longer than 1.5 sample periods) are filled by resampling every
  column onto the uniform grid of the median sample period.
Errors: a map naming a missing column, a non-numeric column, time that does not strictly
increase, a record shorter than `MIN_SAMPLES` samples or `MIN_DURATION_S`, a command that never
moves, and positions or speeds that are implausible for the axis declared in the map's
`plausibility` section (the usual cause: millimetres declared as metres).

Example map (`config/emps_map.yaml`)::

    time: {column: t_s, unit: s}
    position_sensor: motor_encoder
    signals:
      pos_cmd_m: {column: qg_ref_m, unit: m}
      pos_meas_m: {column: qm_meas_m, unit: m}
      force_cmd_N: {column: vir_ctrl_V, unit: V, gain: 35.15}
    plausibility: {travel_m: 0.3, max_speed_m_s: 0.5}
"""

from __future__ import annotations

import csv
import dataclasses
import math
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from feed_twin.io.config import (
    ConfigError,
    from_mapping,
    load_yaml,
    require_positive,
)

MIN_SAMPLES = 200
MIN_DURATION_S = 0.2
MIN_COMMAND_TRAVEL_M = 1e-6  # below one micrometre of commanded travel nothing can be identified
GAP_FACTOR = 1.5  # a time step longer than this many median periods is a gap
MAX_NAN_FRACTION = 0.2  # more missing than this is not repaired

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
VOLTAGE_SIGNALS = ("voltage_d_V", "voltage_q_V")  # the current controller's voltage commands


class MeasuredDataError(ValueError):
    """The measured data cannot be used as it is; the message names the column and the problem."""


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
    # [target SI unit per column unit]; required for V mapped to an effort, else a scale
    gain: float | None = None
    optional: bool = False  # a missing column is skipped instead of an error

    def __post_init__(self) -> None:
        if self.unit not in _UNITS:
            raise ValueError(f"unit = {self.unit!r}: must be one of {', '.join(UNITS)}")
        if self.gain is not None:
            require_positive("gain", self.gain)


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
    time: ColumnSpec
    position_sensor: Literal["motor_encoder", "linear_scale"]
    signals: Any  # name -> ColumnSpec mapping, parsed by load_column_map
    plausibility: Plausibility
    conversion: Conversion = field(default_factory=Conversion)


@dataclass(frozen=True, kw_only=True)
class ColumnMap:
    """A parsed column map: the time column, the mapped signals, and the machine data."""

    time: ColumnSpec
    position_sensor: Literal["motor_encoder", "linear_scale"]
    signals: tuple[tuple[str, ColumnSpec], ...]
    plausibility: Plausibility
    conversion: Conversion
    source: str = "<map>"

    def __post_init__(self) -> None:
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
    if _UNITS[raw.time.unit][0] != "time":
        raise ConfigError(f"{source}: time.unit = {raw.time.unit!r}: must be a time unit")
    try:
        return ColumnMap(
            time=raw.time,
            position_sensor=raw.position_sensor,
            signals=tuple(signals),
            plausibility=raw.plausibility,
            conversion=raw.conversion,
            source=source,
        )
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None


@dataclass(frozen=True, kw_only=True, eq=False)
class MeasuredRun:
    """A measured record on a uniform time base, in SI, with canonical names.

    `signals` maps canonical names to float64 arrays of the same length as `t_s`.
    `warnings` lists the repairs made while loading (interpolated samples, filled gaps).
    """

    source: str
    t_s: np.ndarray
    signals: Mapping[str, np.ndarray]
    position_sensor: str
    warnings: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(
                f"{self.source}: no signal {name!r}; it has {', '.join(self.signals)}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self.signals

    def __iter__(self) -> Iterator[str]:
        return iter(self.signals)

    @property
    def sample_period_s(self) -> float:
        return float((self.t_s[-1] - self.t_s[0]) / (len(self.t_s) - 1))

    @property
    def effort_name(self) -> str | None:
        """The drive-effort signal the record carries (force, torque or q-current), if any."""
        return next((n for n in EFFORT_SIGNALS if n in self.signals), None)

    @property
    def disturbance_names(self) -> tuple[str, ...]:
        return tuple(n for n in self.signals if n.startswith("disturbance_"))

    def with_signals(self, **extra: np.ndarray) -> MeasuredRun:
        merged = dict(self.signals)
        merged.update({k: np.asarray(v, dtype=float) for k, v in extra.items()})
        return dataclasses.replace(self, signals=merged)


def read_csv_table(path: str | Path) -> tuple[list[str], np.ndarray]:
    """Header and float64 table of a CSV file; empty or non-numeric cells become NaN."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            if b"\0" in fh.read(4096):
                raise MeasuredDataError(f"{path}: not a text CSV file (NUL byte: binary data)")
        with path.open(newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh), None)
    except FileNotFoundError:
        raise MeasuredDataError(f"{path}: no such measured file") from None
    except UnicodeDecodeError as exc:
        raise MeasuredDataError(f"{path}: not a UTF-8 text file (byte {exc.start})") from None
    if not header:
        raise MeasuredDataError(f"{path}: the file is empty (no header line)")
    header = [h.strip() for h in header]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "Empty input file": a header alone is checked below
            table = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=float, ndmin=2)
    except ValueError as exc:
        # genfromtxt lists every ragged row ("Line #102 (got 2 columns instead of 5)"): the
        # first one names the problem.
        rows = [ln.strip() for ln in str(exc).splitlines() if ln.strip().startswith("Line #")]
        raise MeasuredDataError(
            f"{path}: {rows[0] if rows else 'rows of different lengths'}"
        ) from None
    if table.size == 0:
        table = np.empty((0, len(header)))
    if table.shape[1] != len(header):
        raise MeasuredDataError(
            f"{path}: the header has {len(header)} columns but the rows have {table.shape[1]}"
        )
    return header, table


def load_measured(path: str | Path, column_map: ColumnMap | str | Path) -> MeasuredRun:
    """Load a measured CSV file (or a rosbag2 recording) through a column map."""
    if not isinstance(column_map, ColumnMap):
        column_map = load_column_map(column_map)
    path = Path(path)
    if path.is_dir() or path.suffix == ".mcap":
        header, table = _read_bag_table(path, column_map)
    else:
        header, table = read_csv_table(path)
    return build_run(str(path), header, table, column_map)


def _read_bag_table(path: Path, column_map: ColumnMap) -> tuple[list[str], np.ndarray]:
    """Bag columns named `<topic>:<field>` (dotted field path, or `log_time_s`).

    Topics other than the time column's are resampled onto its time stamps by their own
    receive times (linear interpolation), so signals from several topics share one time base.
    """
    from feed_twin.io.bag import BagError, BagReader

    specs = [column_map.time] + [spec for _, spec in column_map.signals]
    by_topic: dict[str, list[str]] = {}
    for spec in specs:
        topic, sep, name = spec.column.partition(":")
        if not sep or not topic or not name:
            raise MeasuredDataError(
                f"{path}: map column {spec.column!r} must read '<topic>:<field>' for a bag"
            )
        by_topic.setdefault(topic, [])
        if name != "log_time_s":
            by_topic[topic].append(name)
    try:
        reader = BagReader(path)
        known = {t.name for t in reader.info.topics}
        data: dict[str, dict[str, np.ndarray]] = {}
        for topic, fields in by_topic.items():
            if topic not in known:
                if all(s.optional for s in specs if s.column.startswith(topic + ":")):
                    continue
                raise MeasuredDataError(
                    f"{path}: the map names topic {topic!r}, which the bag lacks; it has "
                    f"{', '.join(sorted(known))}"
                )
            data[topic] = reader.columns(topic, fields)
    except BagError as exc:
        raise MeasuredDataError(str(exc)) from None
    time_topic = column_map.time.column.partition(":")[0]
    base = data[time_topic]["log_time_s"]
    header: list[str] = []
    cols: list[np.ndarray] = []
    for topic, columns in data.items():
        for name, values in columns.items():
            values = np.asarray(values, dtype=float)
            if topic != time_topic:
                values = np.interp(base, columns["log_time_s"], values)
            header.append(f"{topic}:{name}")
            cols.append(values)
    return header, np.column_stack(cols)


def build_run(source: str, header: list[str], table: np.ndarray, cmap: ColumnMap) -> MeasuredRun:
    """Map, repair, convert and check a raw table; see the module docstring for the rules."""
    index = {name: j for j, name in enumerate(header)}
    notes: list[str] = []
    wanted = [("t_s", cmap.time)] + list(cmap.signals)
    missing = [
        f"{spec.column!r} (for {name})"
        for name, spec in wanted
        if spec.column not in index and not spec.optional
    ]
    if missing:
        raise MeasuredDataError(
            f"{source}: the map {cmap.source} names column(s) {', '.join(missing)} that the file "
            f"lacks; it has {', '.join(header)}"
        )
    present = [(name, spec) for name, spec in wanted if spec.column in index]

    t_raw = table[:, index[cmap.time.column]] * _UNITS[cmap.time.unit][1]
    tcol = cmap.time.column
    if np.isnan(t_raw).any():
        row = int(np.flatnonzero(np.isnan(t_raw))[0])
        raise MeasuredDataError(
            f"{source}: time column {tcol!r} is empty or not a number at data row {row + 1}; "
            "time stamps are not interpolated"
        )
    n = len(t_raw)
    dt = np.diff(t_raw)
    if (dt <= 0).any():
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise MeasuredDataError(
            f"{source}: time column {tcol!r} does not increase at data row {row + 1} "
            f"(t = {float(t_raw[row])!r} s after {float(t_raw[row - 1])!r} s); sort the file "
            "or fix the clock"
        )
    if n < MIN_SAMPLES or (n and t_raw[-1] - t_raw[0] < MIN_DURATION_S):
        duration = float(t_raw[-1] - t_raw[0]) if n else 0.0
        raise MeasuredDataError(
            f"{source}: the record is too short ({n} samples, {duration:.3g} s); "
            f"need at least {MIN_SAMPLES} samples and {MIN_DURATION_S} s"
        )
    period = float(np.median(dt))

    columns: dict[str, np.ndarray] = {}
    for name, spec in present[1:]:
        raw = table[:, index[spec.column]].astype(float)
        bad = ~np.isfinite(raw)
        if bad.all():
            raise MeasuredDataError(
                f"{source}: column {spec.column!r} (for {name}) holds no numbers"
            )
        if bad.mean() > MAX_NAN_FRACTION:
            raise MeasuredDataError(
                f"{source}: column {spec.column!r} (for {name}) is {100 * bad.mean():.0f} % "
                f"empty or not a number; at most {100 * MAX_NAN_FRACTION:.0f} % is repaired"
            )
        if bad.any():
            good = ~bad
            raw = raw.copy()
            raw[bad] = np.interp(t_raw[bad], t_raw[good], raw[good])
            notes.append(
                f"column {spec.column!r} ({name}): {int(bad.sum())} empty or NaN sample(s) "
                "linearly interpolated"
            )
        columns[name] = _to_si(name, spec, raw, cmap.conversion)

    gaps = dt > GAP_FACTOR * period
    t = t_raw
    if gaps.any():
        t = t_raw[0] + period * np.arange(int(round((t_raw[-1] - t_raw[0]) / period)) + 1)
        columns = {k: np.interp(t, t_raw, v) for k, v in columns.items()}
        largest = int(np.argmax(dt))
        notes.append(
            f"time column {tcol!r}: {int(gaps.sum())} gap(s) (largest {dt[largest]:.4g} s at "
            f"t = {t_raw[largest]:.4g} s); {len(t) - n} sample(s) inserted by resampling "
            f"every column onto a uniform {period:.4g} s grid"
        )

    run = MeasuredRun(
        source=source,
        t_s=np.asarray(t, dtype=float),
        signals=columns,
        position_sensor=cmap.position_sensor,
        warnings=tuple(notes),
    )
    _check_plausible(run, cmap)
    return run


def _to_si(name: str, spec: ColumnSpec, raw: np.ndarray, conv: Conversion) -> np.ndarray:
    dim, factor = _UNITS[spec.unit]
    gain = 1.0 if spec.gain is None else spec.gain
    if dim in ("angle", "angular_velocity"):
        assert conv.lead_m is not None  # checked when the map was built
        if spec.unit == "counts":
            assert conv.counts_per_rev is not None
            factor = 2.0 * math.pi / conv.counts_per_rev
        factor *= conv.lead_m / (2.0 * math.pi)
    return raw * (factor * gain)


def _check_plausible(run: MeasuredRun, cmap: ColumnMap) -> None:
    lim = cmap.plausibility
    h = run.sample_period_s
    spec_of = dict(cmap.signals)
    for name in ("pos_cmd_m", "pos_meas_m"):
        if name not in run:
            continue
        x = run[name]
        col = spec_of[name].column
        unit = spec_of[name].unit
        span = float(x.max() - x.min())
        if span > 1.5 * lim.travel_m:
            raise MeasuredDataError(
                f"{run.source}: column {col!r} ({name}, declared in {unit}) spans {span:.4g} m, "
                f"more than the axis travel of {lim.travel_m:.4g} m; is the unit wrong "
                f"(mm declared as m)?"
            )
        # 99.9th percentile so that one encoder glitch does not decide
        speed = float(np.percentile(np.abs(np.diff(x)) / h, 99.9))
        if speed > 2.0 * lim.max_speed_m_s:
            raise MeasuredDataError(
                f"{run.source}: column {col!r} ({name}, declared in {unit}) implies a speed of "
                f"{speed:.4g} m/s, more than twice the axis maximum of {lim.max_speed_m_s:.4g} "
                "m/s; is the unit or the time unit wrong?"
            )
    for name in ("vel_cmd_m_s", "vel_meas_m_s"):
        if name in run:
            speed = float(np.percentile(np.abs(run[name]), 99.9))
            if speed > 2.0 * lim.max_speed_m_s:
                spec = spec_of[name]
                raise MeasuredDataError(
                    f"{run.source}: column {spec.column!r} ({name}, declared in {spec.unit}) "
                    f"reaches {speed:.4g} m/s, more than twice the axis maximum of "
                    f"{lim.max_speed_m_s:.4g} m/s; is the unit wrong (mm/min declared as m/s)?"
                )
    if "pos_cmd_m" in run:
        travel = float(np.ptp(run["pos_cmd_m"]))
        if travel < MIN_COMMAND_TRAVEL_M:
            col = spec_of["pos_cmd_m"].column
            raise MeasuredDataError(
                f"{run.source}: column {col!r} (pos_cmd_m) never moves (commanded travel "
                f"{travel:.3g} m < {MIN_COMMAND_TRAVEL_M:g} m); nothing can be compared"
            )
    elif (
        "vel_cmd_m_s" in run
        and float(np.max(np.abs(run["vel_cmd_m_s"]))) * (run.t_s[-1] - run.t_s[0])
        < MIN_COMMAND_TRAVEL_M
    ):
        col = spec_of["vel_cmd_m_s"].column
        raise MeasuredDataError(
            f"{run.source}: column {col!r} (vel_cmd_m_s) never moves; nothing can be compared"
        )
