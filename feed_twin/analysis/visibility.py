"""What a record can show, decided before anything is fitted.

A monitoring log (MTConnect, OPC UA) samples at 1-100 Hz and prints positions rounded for
display: 1 mm or 0.1 mm steps, where the following error of a machine tool is microns to a
fraction of a millimetre. From the record's sample period h, its position resolution q
(`resolution`, estimated from the values themselves) and the following error the nominal twin
expects, this module decides which channels carry evidence and which effects of the library
the record can show:

- the position channel carries evidence only where the twin's following error exceeds q; else
  its weight is floored at the rounding noise q / sqrt(12), and the effects that act on the
  position (microns of lead error, backlash, compliance, thermal growth) are not searched;
- an effect whose signature is faster than the record is not searched: the inverter's dead
  time (within a PWM period), a ripple per motor revolution above half the Nyquist frequency at
  the record's speeds, delays of a few base periods against a sample period many times longer,
  an inertia whose accelerations last fewer than MIN_ACCEL_SAMPLES samples, a Stribeck region
  below the record's velocity resolution q / h, a viscous friction when the record moves at one
  speed only;
- a command that is a staircase of rounding (a slow move advances less than one step per
  sample, so the rounded value stands still between steps) is smoothed through the midpoints
  of its steps (`dequantize`) before it drives the twin; fed as it is, the twin would stop and
  go and name a holding friction from it.
Each effect not searched is listed, with its reason, as "cannot be seen in this record".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from feed_twin.analysis.effects import CHANNEL_DELAY_PERIODS
from feed_twin.analysis.fit import SimOutputs
from feed_twin.analysis.twin import SLOW_COMMAND_S, Twin
from feed_twin.io.measured import MeasuredRun

# quanta tried by `resolution`: 1, 2, 5 x 10^k m (or A) from 1e-12 to 0.5
_LADDER = tuple(m * 10.0**k for k in range(-12, 0) for m in (1.0, 2.0, 5.0))
ON_GRID_FRACTION = 0.98  # a quantum holds when this share of the samples are its multiples
ON_GRID_TOL = 1e-3  # [quanta] how close to a multiple counts as on it (float noise)
STAIRCASE_FRACTION = 0.2  # a staircase: this share of the moving samples stand still
SLOW_RECORD_S = 2e-3  # [s] a record sampled slower than this cannot show a dead time
DELAY_SAMPLES = 4.0  # a delay search shorter than 1/this of the sample period is not searched
SILENT_FACTOR = 100.0  # a channel without evidence is weighted at this many resolution steps
MIN_ACCEL_SAMPLES = 3  # accelerations must span this many samples for the mass to show
ACCEL_NOISE_FACTOR = 3.0  # an acceleration counts above this many times q / h^2
BLIND_NOISE_FACTOR = 1.0  # ... and its effort is no evidence above this many
# [m] the largest position signature of the position-domain effects at their typical sizes
# (thermal growth of 2 K/m over a metre, 10-20 um of backlash, microns of lead error): a
# resolution coarser than this hides them whatever the following error
POSITION_SIGNATURE_M = 2e-5
POSITION_EFFECTS = (
    "lead_error",
    "position_dependent_stiffness",
    "backlash",
    "thermal_drift",
)
# effects that live within a few base periods of the model: delays and the inverter
DELAY_EFFECTS = ("channel_delay", "measurement_delay", "position_delay")
# ripples per motor revolution, with the order of their slowest harmonic
RIPPLE_ORDERS = {"cogging_torque": 2, "current_offset": 1}


def resolution(x: np.ndarray) -> float:
    """The step [signal unit] a signal is rounded to: the largest quantum of 1, 2 or 5 x 10^k
    of which nearly all (ON_GRID_FRACTION) of its samples are multiples; 0 for a signal that is
    not rounded to any (a float computation, a fine encoder). Nearly all, not most: a command
    that dwells on whole millimetres keeps its finer step, and a log printed to 3 significant
    figures (0.1 mm below 100 mm, 1 mm above) reads as its finer step."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return 0.0
    found = 0.0
    for q in _LADDER:
        r = x / q
        if np.mean(np.abs(r - np.round(r)) < ON_GRID_TOL) >= ON_GRID_FRACTION:
            found = q
    return found


def position_resolution(raw: MeasuredRun) -> float:
    """[m] The coarser step of the record's position channels as recorded (0: not rounded)."""
    return max((resolution(raw[n]) for n in ("pos_cmd_m", "pos_meas_m") if n in raw), default=0.0)


def staircase_fraction(x: np.ndarray, q: float) -> float:
    """Share of the samples inside slow moves that stand still: between two single steps of q
    in the same direction, the rounded value holds while the axis moves on."""
    if q <= 0.0:
        return 0.0
    steps = np.flatnonzero(np.diff(x) != 0.0) + 1
    if len(steps) < 2:
        return 0.0
    d = np.diff(x)[steps - 1]
    single = np.abs(np.abs(d) - q) < 0.5 * q
    same = (np.sign(d[1:]) == np.sign(d[:-1])) & single[1:] & single[:-1]
    held = np.sum(np.diff(steps)[same] - 1)
    moving = np.sum(np.diff(steps)[same])
    return float(held / moving) if moving else 0.0


def dequantize(t: np.ndarray, x: np.ndarray, q: float) -> np.ndarray:
    """A rounded staircase smoothed through the midpoints of its steps.

    A value rounded to q changes when the true value crosses a midpoint between two levels, so
    each single step of q marks a point of the true motion: half-way between the two samples,
    at the mid level. Between two such points in the same direction the axis moved on (linear
    interpolation); a level held between steps of opposite direction, or at the record's ends,
    is a rest and is held. Steps of several q (a fast move) keep their samples."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    change = np.flatnonzero(np.diff(x) != 0.0) + 1
    if len(change) == 0:
        return x.copy()
    d = x[change] - x[change - 1]
    # a staircase step: one q, with the level held for a sample before or after it (a move
    # slower than a step per sample); at a step or more per sample the samples are the motion
    held_before = np.concatenate(([True], np.diff(change) > 1))
    held_after = np.concatenate((np.diff(change) > 1, [True]))
    single = (np.abs(np.abs(d) - q) < 0.5 * q) & (held_before | held_after)
    # a step joins the next when both are single steps in the same direction: a slow move
    joined = single[1:] & single[:-1] & (np.sign(d[1:]) == np.sign(d[:-1]))
    knots = [(float(t[0]), float(x[0]))]
    for j, i in enumerate(change):
        if not (j > 0 and joined[j - 1]):  # the level before was held up to this step
            knots.append((float(t[i - 1]), float(x[i - 1])))
        if single[j]:
            knots.append((float(0.5 * (t[i - 1] + t[i])), float(0.5 * (x[i - 1] + x[i]))))
        if not (j + 1 < len(change) and joined[j]):  # the new level is held from here
            knots.append((float(t[i]), float(x[i])))
    knots.append((float(t[-1]), float(x[-1])))
    kt, first = np.unique(np.array([k[0] for k in knots]), return_index=True)
    return np.interp(t, kt, np.array([k[1] for k in knots])[first])


@dataclass(frozen=True, kw_only=True)
class Unseen:
    """An effect the record cannot show, and why (one line)."""

    name: str
    reason: str


@dataclass(frozen=True, kw_only=True)
class Visibility:
    """What the record can show: its channels' resolution and evidence, the effects searched
    and those it cannot show."""

    sample_period_s: float
    position_resolution_m: float  # 0: not rounded
    effort_resolution: float  # [effort SI unit] 0: not rounded
    fe_expected_max_m: float  # largest following error of the nominal twin while moving
    position_evidence: bool
    velocity_resolution_m_s: float  # q / h: the speed one step per sample means
    unseen: tuple[Unseen, ...]
    notes: tuple[str, ...] = ()
    # samples whose effort carries an inertial force the record does not resolve (the command
    # accelerates there within a sample or two, and the mass cannot be seen): no evidence
    blind: np.ndarray | None = field(default=None, repr=False)

    @property
    def unseen_names(self) -> tuple[str, ...]:
        return tuple(u.name for u in self.unseen)

    def lines(self) -> list[str]:
        """The record's view in short lines, for the progress output and the report."""
        q = self.position_resolution_m
        rate = 1.0 / self.sample_period_s
        head = (
            f"record: {rate:.4g} Hz, position resolution "
            + (f"{_length(q)}" if q > 0 else "finer than the numbers' precision")
            + f", following error of the nominal twin up to {_length(self.fe_expected_max_m)}"
        )
        out = [head]
        if not self.position_evidence:
            out.append(
                "the position channel carries no evidence: the following error is below the "
                "resolution, so set minus actual shows the rounding; it is not fitted or tested"
            )
        out += [f"cannot be seen in this record: {u.name}: {u.reason}" for u in self.unseen]
        if self.blind is not None and self.blind.any():
            out.append(
                f"{int(self.blind.sum())} samples ({100 * float(self.blind.mean()):.2g} %) fall "
                "in accelerations the record does not resolve: their effort is left out of the "
                "evidence"
            )
        return out + list(self.notes)

    def as_dict(self) -> dict[str, object]:
        return {
            "sample_period_s": self.sample_period_s,
            "position_resolution_m": self.position_resolution_m,
            "effort_resolution": self.effort_resolution,
            "fe_expected_max_m": self.fe_expected_max_m,
            "position_evidence": self.position_evidence,
            "velocity_resolution_m_s": self.velocity_resolution_m_s,
            "cannot_be_seen": {u.name: u.reason for u in self.unseen},
            "effort_samples_left_out": 0 if self.blind is None else int(self.blind.sum()),
        }


def _length(x: float) -> str:
    """A length [m] in the unit that reads best, to 2 (mm) or 3 significant figures."""
    if x >= 1e-3:
        return f"{x * 1e3:.2g} mm"
    if x >= 1e-6:
        return f"{x * 1e6:.3g} um"
    return f"{x * 1e9:.3g} nm"


def smooth_staircases(run: MeasuredRun) -> tuple[MeasuredRun, list[str]]:
    """The run with its rounded position channels smoothed (module docstring), and a note for
    each, in a record slower than SLOW_COMMAND_S (whose command the twin interpolates by a
    cubic): staircases through the midpoints of their steps, then the rounding's jitter at the
    Nyquist frequency (steps of 1 and 2 q alternating at 1.5 q per sample) removed by the
    [1 2 1] / 4 filter, which keeps straight moves and rests as they are. Fed as it is, that
    jitter made the twin's effort at the samples swing by a hundred newtons."""
    notes = []
    changed = {}
    slow = run.sample_period_s > SLOW_COMMAND_S
    for name in ("pos_cmd_m", "pos_meas_m"):
        if name not in run:
            continue
        x = run[name]
        q = resolution(x)
        if q <= 0.0 or not slow:
            continue
        share = staircase_fraction(x, q)
        if share >= STAIRCASE_FRACTION:
            x = dequantize(run.t_s, x, q)
        changed[name] = _binomial(x)
        notes.append(
            f"{name} is rounded to {_length(q)}"
            + (
                f" and a staircase ({100 * share:.0f} % of its samples in slow moves stand "
                "still): smoothed through the midpoints of its steps, not fed to the twin as "
                "stop-and-go, and"
                if share >= STAIRCASE_FRACTION
                else ":"
            )
            + " its rounding jitter filtered ([1 2 1] / 4)"
        )
    if not changed:
        return run, notes
    return run.with_signals(**changed), notes


def _binomial(x: np.ndarray) -> np.ndarray:
    """[1 2 1] / 4 over the samples, the ends kept: zero gain at the Nyquist frequency, exact
    on straight lines."""
    y = x.copy()
    y[1:-1] = 0.25 * x[:-2] + 0.5 * x[1:-1] + 0.25 * x[2:]
    return y


def assess(
    run: MeasuredRun, twin: Twin, pos_cmd_m: np.ndarray, out0: SimOutputs, *, raw: MeasuredRun
) -> Visibility:
    """What `run` can show of the model `twin` (whose nominal response is `out0` on the command
    `pos_cmd_m`); `raw`: the run as recorded (before `smooth_staircases`), whose rounding is
    the resolution. See the module docstring for the rules."""
    h = run.sample_period_s
    q = position_resolution(raw)
    name = run.effort_name
    qe = resolution(raw[name]) if name is not None else 0.0
    v = np.gradient(pos_cmd_m, h)
    speed = np.abs(v)
    moving = speed > max(1e-6, 0.05 * float(np.max(speed)))
    fe = np.abs(pos_cmd_m - out0.x_m[0])
    fe_max = float(np.max(fe[moving])) if moving.any() else 0.0
    position_evidence = q <= 0.0 or fe_max > q
    unseen: list[Unseen] = []
    if q > 0.0 and (not position_evidence or q > POSITION_SIGNATURE_M):
        why = (
            f"its signature on the position (microns) is below the record's resolution {_length(q)}"
        )
        unseen += [Unseen(name=e, reason=why) for e in POSITION_EFFECTS]
    unseen += _fast_effects(run, twin, speed[moving], h)
    unseen += _slow_motion_effects(twin, v, moving, h, q)
    blind = None
    if "mass_error" in [u.name for u in unseen]:
        blind = unresolved(v, h, q)
        unseen.append(
            Unseen(
                name="torque_constant_error",
                reason="with the accelerations unresolved only the inertia could tell a scale "
                "of the whole effort from the friction and weight forces: the forces named are "
                "in units of the nominal force constant",
            )
        )
    return Visibility(
        sample_period_s=h,
        position_resolution_m=q,
        effort_resolution=qe,
        fe_expected_max_m=fe_max,
        position_evidence=position_evidence,
        velocity_resolution_m_s=q / h,
        unseen=tuple(unseen),
        blind=blind,
    )


def _fast_effects(run: MeasuredRun, twin: Twin, speeds: np.ndarray, h: float) -> list[Unseen]:
    """Effects whose signature lives on a time scale shorter than the record's samples."""
    out: list[Unseen] = []
    base = twin.base_period_s
    searched = CHANNEL_DELAY_PERIODS * base
    if h > DELAY_SAMPLES * searched:
        why = (
            f"the delays searched (up to {searched * 1e3:.2g} ms) are under 1/{DELAY_SAMPLES:g} of "
            f"the record's {h * 1e3:.3g} ms sample period"
        )
        out += [Unseen(name=e, reason=why) for e in DELAY_EFFECTS]
    if h > SLOW_RECORD_S:
        out.append(
            Unseen(
                name="dead_time",
                reason=f"the inverter's dead time acts within each PWM period, the record "
                f"samples every {h * 1e3:.3g} ms",
            )
        )
    lead = twin.lead_m
    nyquist = 0.5 / h
    if lead and len(speeds):
        v_typ = float(np.median(speeds))
        for effect, order in RIPPLE_ORDERS.items():
            k = order * (twin.pole_pairs or 1) if effect == "current_offset" else order * 3
            f = k * v_typ / lead
            if f > 0.5 * nyquist:
                out.append(
                    Unseen(
                        name=effect,
                        reason=f"its ripple runs at {f:.3g} Hz at the record's median speed "
                        f"({v_typ * 1e3:.3g} mm/s), above half its Nyquist frequency "
                        f"({nyquist:.3g} Hz)",
                    )
                )
    return out


def _slow_motion_effects(
    twin: Twin, v: np.ndarray, moving: np.ndarray, h: float, q: float
) -> list[Unseen]:
    """Effects that need the record to resolve accelerations, low speeds or two speeds."""
    out: list[Unseen] = []
    # how long the command takes to reach its fast speeds at its largest acceleration: a
    # machine that gets there within a sample or two leaves its inertia between the samples
    speeds = np.abs(v[moving])
    a_peak = float(np.percentile(np.abs(np.gradient(v, h)), 99.5))
    v_fast = float(np.percentile(speeds, 90)) if len(speeds) else 0.0
    t_acc = v_fast / a_peak if a_peak > 0 else math.inf
    if t_acc < MIN_ACCEL_SAMPLES * h:
        out.append(
            Unseen(
                name="mass_error",
                reason=f"the command reaches its fast speeds ({v_fast * 1e3:.3g} mm/s) within "
                f"{t_acc:.2g} s ({a_peak:.2g} m/s^2), under {MIN_ACCEL_SAMPLES} samples: the "
                "inertia's force comes and goes between samples",
            )
        )
    v_res = q / h if q > 0 else 0.0
    friction = twin.doc.friction()
    v_s = None
    if friction is not None and twin.doc.has_slot(f"{friction}.v_s"):
        v_s = twin.doc.get(f"{friction}.v_s")
    if v_s is not None and v_res > v_s:
        out.append(
            Unseen(
                name="stribeck_friction",
                reason=f"the Stribeck region (below about {v_s * 1e3:.2g} mm/s) lies under the "
                f"record's velocity resolution ({v_res * 1e3:.2g} mm/s: one step per sample)",
            )
        )
    if len(speeds) and np.percentile(speeds, 90) < 1.5 * max(np.percentile(speeds, 10), 1e-12):
        out.append(
            Unseen(
                name="viscous_friction",
                reason=f"the record moves at one speed ({np.median(speeds) * 1e3:.3g} mm/s): a "
                "force proportional to it cannot be told from a constant one",
            )
        )
    return out


def unresolved(v: np.ndarray, h: float, q: float) -> np.ndarray:
    """Samples whose effort carries an acceleration of the command `v` [m/s] above the
    rounding's noise, and the samples next to them: the machine's acceleration lasts part of
    a sample, the record's is smeared over two."""
    accel = _accelerating(v, h, q, factor=BLIND_NOISE_FACTOR)
    return accel | np.roll(accel, 1) | np.roll(accel, -1)


def _accelerating(
    v: np.ndarray, h: float, q: float, *, factor: float = ACCEL_NOISE_FACTOR
) -> np.ndarray:
    """Samples where the command accelerates: above the rounding's own acceleration noise
    (about q / h^2, `factor` times) and a thousandth of the largest."""
    a = np.abs(np.gradient(v, h))
    return a > max(factor * q / h**2, 1e-3 * float(np.max(a)))


def force_constant_correlation(run: MeasuredRun, out0: SimOutputs, v: np.ndarray) -> str | None:
    """A line saying how far the force constant can be told apart from friction and weight:
    the share of the nominal twin's effort explained by a constant, sign(v) and v (a scale of
    the whole effort and those forces are one unknown where the effort is mostly friction)."""
    if out0.effort is None or run.effort_name is None:
        return None
    e = out0.effort[0]
    basis = np.column_stack((np.ones_like(v), np.tanh(v / max(1e-6, 0.05 * np.max(np.abs(v)))), v))
    coef, *_ = np.linalg.lstsq(basis, e, rcond=None)
    spread = float(np.sum((e - e.mean()) ** 2))
    if spread == 0.0:
        return None
    r2 = 1.0 - float(np.sum((e - basis @ coef) ** 2)) / spread
    r = math.sqrt(max(r2, 0.0))
    if r < 0.9:
        return (
            f"force constant (torque_constant_error) vs friction and weight: correlation "
            f"{r:.2f}; the accelerations tell them apart"
        )
    return (
        f"force constant (torque_constant_error) vs friction and weight: correlation {r:.2f}; "
        "in this record a scale of the whole effort and the friction and weight forces are "
        "nearly one unknown: the forces named are in units of the nominal force constant"
    )


def with_floor(floors: dict[str, float], vis: Visibility) -> dict[str, float]:
    """A slow record's noise floors raised to their rounding noise (q / sqrt(12)); a position
    channel without evidence to SILENT_FACTOR times its resolution (it must not steer a fit
    with the twin's microns against the record's rounding)."""
    out = dict(floors)
    if vis.sample_period_s <= SLOW_COMMAND_S:
        # a drive trace (1 kHz, 50 Hz): its encoder's step sits under its sample noise, and its
        # weights stay as the workflow's figures were made with
        return out
    q = vis.position_resolution_m
    if q > 0 and "position" in out:
        least = q / math.sqrt(12.0) if vis.position_evidence else SILENT_FACTOR * q
        out["position"] = max(out["position"], least)
    if vis.effort_resolution > 0 and "effort" in out:
        out["effort"] = max(out["effort"], vis.effort_resolution / math.sqrt(12.0))
    return out


__all__ = [
    "Unseen",
    "Visibility",
    "assess",
    "dequantize",
    "force_constant_correlation",
    "position_resolution",
    "resolution",
    "smooth_staircases",
    "unresolved",
    "with_floor",
]
