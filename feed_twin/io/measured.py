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
Time comes from the map's time column, or from the row index at a rate (`time: {index: true,
rate_hz: 10}` in the map, or `--rate HZ`): a monitoring log has no time column. Rows are named
`file:line` (the header is line 1) in every complaint about them.
Errors: a map naming a missing column, a non-numeric column, time that does not strictly
increase (a repeated stamp, or rows out of order), a record shorter than `MIN_SAMPLES`
samples or `MIN_DURATION_S`, a command that never moves, and positions or speeds that are
implausible for the axis declared in the map's `plausibility` section (the usual cause:
millimetres declared as metres, or a log's rows out of order). They look at the part of the
record that is used (`load_measured(window=...)`).

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
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from feed_twin.io.column_map import (  # noqa: F401  (the map's names, re-exported)
    _UNITS,
    EFFORT_SIGNALS,
    EFFORT_UNITS,
    UNITS,
    VOLTAGE_SIGNALS,
    ColumnMap,
    ColumnSpec,
    Conversion,
    Plausibility,
    RowTime,
    canonical_dimension,
    load_column_map,
)

MIN_SAMPLES = 200
MIN_DURATION_S = 0.2
MIN_COMMAND_TRAVEL_M = 1e-6  # below one micrometre of commanded travel nothing can be identified
GAP_FACTOR = 1.5  # a time step longer than this many median periods is a gap
MAX_NAN_FRACTION = 0.2  # more missing than this is not repaired
MAX_PERIOD_S = 1.0  # [s] a record is sampled at 1 Hz or faster (monitoring logs: 1-100 Hz)
# a sample period (and a period against the model's base period) is taken as equal within this
# relative tolerance: 0.1 s stamps printed as 0.10000000000000142 are 0.1 s, and so are the
# stamps of a `gain: 0.0999999` time column
PERIOD_RTOL = 1e-4
MAX_GRID_FACTOR = 2.0  # filling the gaps may at most double the samples
# rows out of order: all positions jump at a few rows; at more than this fraction of the rows
# the record as a whole is too fast (a unit mistake)
MAX_JUMP_FRACTION = 0.05


class MeasuredDataError(ValueError):
    """The measured data cannot be used as it is; the message names the column and the problem."""


def segment(run: MeasuredRun, t0_s: float, t1_s: float) -> MeasuredRun:
    """The part of `run` with t0 <= t <= t1 [s] (a record's own time stamps). A planned
    command stays whole: it lies on the same clock."""
    t = run.t_s
    if not (t0_s < t1_s):
        raise MeasuredDataError(f"{run.source}: segment {t0_s:g}:{t1_s:g}: t0 must be < t1")
    half = 0.5 * run.sample_period_s  # a bound on a sample belongs to the segment
    keep = (t >= t0_s - half) & (t <= t1_s + half)
    if int(keep.sum()) < MIN_SAMPLES:
        raise MeasuredDataError(
            f"{run.source}: segment {t0_s:g}:{t1_s:g} holds {int(keep.sum())} samples (the "
            f"record runs {t[0]:.6g} to {t[-1]:.6g} s); need at least {MIN_SAMPLES}"
        )
    return dataclasses.replace(
        run,
        t_s=t[keep],
        signals={k: v[keep] for k, v in run.signals.items()},
        source=f"{run.source} [{t0_s:g} s to {t1_s:g} s]",
        lines=None if run.lines is None else run.lines[keep],
        file=run.file,
        effort_blind=None if run.effort_blind is None else run.effort_blind[keep],
    )


def parse_segment(text: str) -> tuple[float, float]:
    """`t0:t1` [s] -> (t0, t1); raises MeasuredDataError naming the text."""
    t0, sep, t1 = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(t0), float(t1)
    except ValueError:
        raise MeasuredDataError(
            f"--segment {text!r}: expected t0:t1 in seconds, e.g. 2.5:14"
        ) from None


@dataclass(frozen=True, kw_only=True, eq=False)
class PlannedCommand:
    """The NC's command at its own interpolation period, on the record's clock: what a record
    without a command is driven with once its program is planned (analysis.program). A trace
    slower than the NC samples it too coarsely: a stop's final approach lasts a few of the
    NC's periods and falls between two 50 Hz samples."""

    t_s: np.ndarray  # [s] uniform, the NC's period apart
    pos_m: np.ndarray  # [m] position setpoint
    vel_m_s: np.ndarray  # [m/s] velocity setpoint
    acc_m_s2: np.ndarray  # [m/s^2] acceleration setpoint

    @property
    def setpoints(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position, velocity, acceleration), the order of the NC's setpoint rows."""
        return self.pos_m, self.vel_m_s, self.acc_m_s2


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
    trace_filter: Literal["none", "mean"] = "none"  # see ColumnMap.trace_filter
    effort_sample: Literal["actual", "setpoint"] = "actual"  # see ColumnMap.effort_sample
    plan: PlannedCommand | None = None  # the command at the NC's period, if planned
    # the measured position's zero is not known (a command placed from the program, whose
    # offset is only estimated): the position channel compares shapes, not levels
    position_offset_free: bool = False
    # the file line of each sample (the header is line 1; -1 where a gap was filled), and the
    # file: rows are named `file:line` in every complaint about them
    lines: np.ndarray | None = None
    file: str = ""
    # samples whose effort is no evidence for the model (a slow record's accelerations, which
    # fall between its samples: analysis.visibility); left out of residuals and fits
    effort_blind: np.ndarray | None = None

    def where(self, sample: int) -> str:
        """`file:line` of sample `sample`, or its time where the sample has no line."""
        line = -1 if self.lines is None else int(self.lines[sample])
        if line < 0:
            return f"{self.source} at t = {float(self.t_s[sample]):.6g} s"
        return f"{self.file or self.source}:{line}"

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
        text = path.read_bytes()
    except FileNotFoundError:
        raise MeasuredDataError(f"{path}: no such measured file") from None
    except IsADirectoryError:
        raise MeasuredDataError(f"{path}: is a directory, not a CSV file or a bag") from None
    zero = text.find(b"\0", 0, 65536)
    if zero >= 0:
        raise MeasuredDataError(
            f"{path}: is not a text CSV (binary data at byte {zero}); export the record as CSV"
        )
    try:
        lines = text.decode("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise MeasuredDataError(
            f"{path}: is not a UTF-8 text CSV (byte {exc.start} cannot be decoded)"
        ) from None
    header = next(csv.reader(lines[:1]), None)
    if not header:
        raise MeasuredDataError(f"{path}: the file is empty (no header line)")
    header = [h.strip() for h in header]
    for number, line in enumerate(lines[1:], start=2):
        cells = line.count(",") + 1
        if line.strip() and cells != len(header):
            raise MeasuredDataError(
                f"{path}: line {number} has {cells} cells but the header has {len(header)} "
                "columns (a ragged or truncated file)"
            )
    rows = [line for line in lines[1:] if line.strip()]
    if not rows:
        # numpy's genfromtxt would warn "Empty input file" on stderr and return nothing
        raise MeasuredDataError(
            f"{path}: has a header ({len(header)} columns) but no data rows; export the record "
            "with its samples"
        )
    table = np.genfromtxt(rows, delimiter=",", dtype=float, ndmin=2)
    return header, table


def load_measured(
    path: str | Path,
    column_map: ColumnMap | str | Path,
    *,
    rate_hz: float | None = None,
    window: tuple[float, float] | None = None,
) -> MeasuredRun:
    """Load a measured CSV file (or a rosbag2 recording) through a column map.

    `rate_hz`: time is the row index at this rate (a log without a time column; overrides the
    map's time). `window` (t0, t1) [s]: only that part of the record is kept, and the
    plausibility checks look at that part only."""
    if not isinstance(column_map, ColumnMap):
        column_map = load_column_map(column_map)
    if rate_hz is not None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise MeasuredDataError(f"--rate {rate_hz!r}: must be a positive number of rows/s")
        column_map = dataclasses.replace(column_map, time=RowTime(index=True, rate_hz=rate_hz))
    path = Path(path)
    if path.is_dir() or path.suffix == ".mcap":
        if not isinstance(column_map.time, ColumnSpec):
            raise MeasuredDataError(f"{path}: a bag's time is a topic field, not a row rate")
        header, table = _read_bag_table(path, column_map)
    else:
        header, table = read_csv_table(path)
    run = build_run(str(path), header, table, column_map, check=False)
    if window is not None:
        run = segment(run, *window)
    check_plausible(run, column_map)
    return run


def _read_bag_table(path: Path, column_map: ColumnMap) -> tuple[list[str], np.ndarray]:
    """Bag columns named `<topic>:<field>` (dotted field path, or `log_time_s`).

    Topics other than the time column's are resampled onto its time stamps (linear
    interpolation), so signals from several topics share one time base: by the same stamp field
    as the time column's (`header.stamp`) where their messages have it, else by receive times.
    Stamps, not receive times, where they exist: a lockstep run of the node set publishes in
    simulation time while the recorder logs wall-clock arrivals in bursts, and lining topics up
    by arrival gave the command jumps of metres per second.
    """
    from feed_twin.io.bag import BagError, BagReader

    assert isinstance(column_map.time, ColumnSpec)  # checked by load_measured
    specs = [column_map.time] + [spec for _, spec in column_map.signals]
    time_topic, _, time_field = column_map.time.column.partition(":")
    stamp = None if time_field == "log_time_s" else time_field
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
            data[topic] = _stamped_columns(reader, topic, fields, stamp)
    except BagError as exc:
        raise MeasuredDataError(str(exc)) from None

    def axis(columns: dict[str, np.ndarray], other: dict[str, np.ndarray]) -> str:
        # stamps left at zero (a publisher that does not set them) do not order anything
        if stamp is None or stamp not in columns or stamp not in other:
            return "log_time_s"
        return stamp if np.all(np.diff(columns[stamp]) > 0) else "log_time_s"

    base = data[time_topic]
    header: list[str] = []
    cols: list[np.ndarray] = []
    for topic, columns in data.items():
        for name, values in columns.items():
            values = np.asarray(values, dtype=float)
            if topic != time_topic:
                by = axis(columns, base)
                values = np.interp(base[by], columns[by], values)
            header.append(f"{topic}:{name}")
            cols.append(values)
    return header, np.column_stack(cols)


def _stamped_columns(reader, topic: str, fields: list[str], stamp: str | None):
    """The topic's fields, with the stamp field too where its messages carry one."""
    from feed_twin.io.bag import BagError

    if stamp is None or stamp in fields:
        return reader.columns(topic, fields)
    try:
        return reader.columns(topic, [*fields, stamp])
    except BagError:
        return reader.columns(topic, fields)


def build_run(
    source: str, header: list[str], table: np.ndarray, cmap: ColumnMap, *, check: bool = True
) -> MeasuredRun:
    """Map, repair, convert and check a raw table; see the module docstring for the rules.
    `check=False` leaves the plausibility checks to the caller (on the segment it uses)."""
    index = {name: j for j, name in enumerate(header)}
    notes: list[str] = []
    if cmap.time is None:
        raise MeasuredDataError(
            f"{source}: the map {cmap.source} gives no time; name the time column (time: "
            "{column: ..., unit: s}), or give the rows' rate (time: {index: true, rate_hz: 10} "
            "or --rate HZ)"
        )
    timed = isinstance(cmap.time, ColumnSpec)
    wanted = list(cmap.signals)
    if isinstance(cmap.time, ColumnSpec):
        wanted.insert(0, ("t_s", cmap.time))
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
    present = [(name, spec) for name, spec in cmap.signals if spec.column in index]
    t_raw, tcol = _time_of(source, table, index, cmap)
    n = len(t_raw)
    dt = np.diff(t_raw)
    if n < MIN_SAMPLES or (n and t_raw[-1] - t_raw[0] < MIN_DURATION_S):
        duration = float(t_raw[-1] - t_raw[0]) if n else 0.0
        raise MeasuredDataError(
            f"{source}: the record is too short ({n} samples, {duration:.3g} s); "
            f"need at least {MIN_SAMPLES} samples and {MIN_DURATION_S} s"
        )
    period = float(np.median(dt))
    if period > MAX_PERIOD_S * (1.0 + PERIOD_RTOL):
        raise MeasuredDataError(
            f"{source}: time column {tcol!r} (declared in {getattr(cmap.time, 'unit', 's')}) "
            f"gives a sample period of {period:.4g} s, slower than any record the twin can "
            f"compare (> {MAX_PERIOD_S:g} s); is the time unit wrong (ms declared as s)?"
        )
    if timed and getattr(cmap.time, "unit", "s") == "s" and abs(period - 1.0) <= PERIOD_RTOL:
        # a 1 kHz trace stamped in ms and declared in s reads exactly as a 1 Hz log: a time
        # column cannot tell them apart, the row index at a stated rate can
        raise MeasuredDataError(
            f"{source}: time column {tcol!r} (declared in s) gives a sample period of 1 s, which "
            "is what a 1 kHz trace stamped in ms declared as s gives: declare its unit as ms, "
            "or, for a log really sampled at 1 Hz, take time from the row index "
            "(time: {index: true, rate_hz: 1} in the map, or --rate 1)"
        )
    if (t_raw[-1] - t_raw[0]) / period > MAX_GRID_FACTOR * n:
        raise MeasuredDataError(
            f"{source}: time column {tcol!r}: a gap of {float(dt.max()):.4g} s in a record "
            f"sampled every {period:.4g} s would take {int((t_raw[-1] - t_raw[0]) / period)} "
            f"samples to fill; cut the record at the gap (--segment t0:t1)"
        )
    if timed and np.all(np.abs(dt - period) <= PERIOD_RTOL * period):
        # stamps printed with float noise (0.1 s as 0.10000000000000142): the uniform grid
        t_raw = np.linspace(t_raw[0], t_raw[-1], n)
    columns: dict[str, np.ndarray] = {}
    for name, spec in present:
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
    lines = np.arange(n) + 2  # the header is line 1
    if gaps.any():
        t = t_raw[0] + period * np.arange(int(round((t_raw[-1] - t_raw[0]) / period)) + 1)
        columns = {k: np.interp(t, t_raw, v) for k, v in columns.items()}
        first, largest = int(np.flatnonzero(gaps)[0]), int(np.argmax(dt))
        near = np.clip(np.searchsorted(t_raw, t - 0.5 * period), 0, n - 1)
        lines = np.where(np.abs(t_raw[near] - t) < 0.5 * period, near + 2, -1)
        notes.append(
            f"time column {tcol!r}: {int(gaps.sum())} gap(s), rows missing (the first after "
            f"{source}:{first + 2}, the largest {dt[largest]:.4g} s after {source}:"
            f"{largest + 2}); {len(t) - n} sample(s) inserted by resampling every column onto a "
            f"uniform {period:.4g} s grid"
        )

    run = MeasuredRun(
        source=source,
        t_s=np.asarray(t, dtype=float),
        signals=columns,
        position_sensor=cmap.position_sensor,
        warnings=tuple(notes),
        trace_filter=cmap.trace_filter,
        effort_sample=cmap.effort_sample,
        lines=lines,
        file=source,
    )
    if check:
        check_plausible(run, cmap)
    return run


def _time_of(
    source: str, table: np.ndarray, index: dict[str, int], cmap: ColumnMap
) -> tuple[np.ndarray, str]:
    """(time stamps [s], what they come from) of a table: the time column, checked to rise
    strictly with the offending rows named, or the row index at the map's rate."""
    if isinstance(cmap.time, RowTime):
        return np.arange(len(table)) / cmap.time.rate_hz, f"row index at {cmap.time.rate_hz:g} Hz"
    assert cmap.time is not None
    tcol = cmap.time.column
    t_raw = cmap.time.to_si(table[:, index[tcol]])
    if np.isnan(t_raw).any():
        row = int(np.flatnonzero(np.isnan(t_raw))[0])
        raise MeasuredDataError(
            f"{source}:{row + 2}: time column {tcol!r} is empty or not a number; time stamps "
            "are not interpolated"
        )
    dt = np.diff(t_raw)
    if (dt <= 0).any():
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        now, before = float(t_raw[row]), float(t_raw[row - 1])
        if now == before:
            raise MeasuredDataError(
                f"{source}:{row + 2}: time column {tcol!r} repeats t = {now!r} s of line "
                f"{row + 1}; drop the repeated row (a logger that wrote one sample twice)"
            )
        later = int(np.flatnonzero(dt < 0).size)
        raise MeasuredDataError(
            f"{source}:{row + 2}: time column {tcol!r} goes back from {before!r} s to {now!r} s "
            f"({later} such step(s) in the file): rows out of order; sort the file by its time "
            "column"
        )
    return t_raw, tcol


def _to_si(name: str, spec: ColumnSpec, raw: np.ndarray, conv: Conversion) -> np.ndarray:
    dim, factor = _UNITS[spec.unit]
    if dim not in ("angle", "angular_velocity"):
        return spec.to_si(raw)
    gain = 1.0 if spec.gain is None else spec.gain
    assert conv.lead_m is not None  # checked when the map was built
    if spec.unit == "counts":
        assert conv.counts_per_rev is not None
        factor = 2.0 * math.pi / conv.counts_per_rev
    factor *= conv.lead_m / (2.0 * math.pi)
    return (raw - spec.offset) * (factor * gain)


def _check_row_order(run: MeasuredRun, cmap: ColumnMap) -> None:
    """Rows out of order or missing in a log timed by its row index: every position channel
    jumps at the same row by more than the axis can travel in one sample (a glitch of one
    sensor moves one channel; a block of rows from elsewhere in the file moves them all)."""
    names = [n for n in ("pos_cmd_m", "pos_meas_m") if n in run]
    if not names:
        return
    limit = 2.0 * cmap.plausibility.max_speed_m_s * run.sample_period_s
    jumps = np.all([np.abs(np.diff(run[n])) > limit for n in names], axis=0)
    if not jumps.any() or jumps.mean() > MAX_JUMP_FRACTION:
        return  # none, or the whole record too fast: a unit, not the rows (check_plausible)
    first = int(np.flatnonzero(jumps)[0]) + 1
    col = dict(cmap.signals)[names[0]].column
    step = float(run[names[0]][first] - run[names[0]][first - 1])
    raise MeasuredDataError(
        f"{run.where(first)}: column {col!r} ({names[0]}) jumps {step:.4g} m from the row "
        f"before, more than the axis travels in one sample ({limit:.4g} m at "
        f"{cmap.plausibility.max_speed_m_s:.4g} m/s), as every position channel does there "
        f"({int(jumps.sum())} such row(s)): rows out of order or missing; sort the file by its "
        "time or sequence column, or cut the record there (--segment t0:t1)"
    )


def check_plausible(run: MeasuredRun, cmap: ColumnMap) -> None:
    """Raise MeasuredDataError where the run's positions, speeds or channels cannot be the
    axis's (see the module docstring)."""
    lim = cmap.plausibility
    h = run.sample_period_s
    spec_of = dict(cmap.signals)
    for name in ("pos_meas_m", *EFFORT_SIGNALS, *VOLTAGE_SIGNALS):
        if name in run and float(np.ptp(run[name])) == 0.0:
            raise MeasuredDataError(
                f"{run.source}: column {spec_of[name].column!r} ({name}) holds one value "
                f"({run[name][0]:.6g} in SI) all along; a frozen or unconnected channel "
                "carries nothing to compare"
            )
    _check_row_order(run, cmap)
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
        steps = np.abs(np.diff(x)) / h
        speed = float(np.percentile(steps, 99.9))
        if speed > 2.0 * lim.max_speed_m_s:
            jumps = np.flatnonzero(steps > 2.0 * lim.max_speed_m_s)
            first = int(jumps[0]) + 1
            raise MeasuredDataError(
                f"{run.where(first)}: column {col!r} ({name}, declared in {unit}) jumps "
                f"{float(x[first] - x[first - 1]):.4g} m in one sample "
                f"({float(steps[first - 1]):.4g} m/s, more than twice the axis maximum of "
                f"{lim.max_speed_m_s:.4g} m/s; "
                f"{jumps.size} such step(s)): rows out of order or missing, or a wrong unit or "
                "time unit?"
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
