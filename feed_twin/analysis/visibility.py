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
- a command that is a staircase of rounding is smoothed before it drives the twin
  (analysis.rounding); where the step grows with the value (significant figures), what the
  record can show is decided at its coarsest step.
Each effect not searched is listed, with its reason, as "cannot be seen in this record".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from feed_twin.analysis.drive_stage import expandable
from feed_twin.analysis.effects import CHANNEL_DELAY_PERIODS
from feed_twin.analysis.fit import SimOutputs
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.rounding import (
    length_text,
    mixed_steps,
    position_resolution,
    resolution,
    smooth_staircases,
)
from feed_twin.analysis.twin import SLOW_COMMAND_S, Twin
from feed_twin.io.measured import MeasuredRun

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
DELAY_EFFECTS = ("channel_delay", "command_delay", "measurement_delay", "position_delay")
# ripples per motor revolution, with the order of their slowest harmonic
RIPPLE_ORDERS = {"cogging_torque": 2, "current_offset": 1}


@dataclass(frozen=True, kw_only=True)
class Unseen:
    """An effect the record cannot show (or the model cannot carry: `by_model`), and why (one
    line)."""

    name: str
    reason: str
    by_model: bool = False

    def line(self) -> str:
        where = "not searched with this model" if self.by_model else "cannot be seen in this record"
        return f"{where}: {self.name}: {self.reason}"


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
            + (f"{length_text(q)}" if q > 0 else "finer than the numbers' precision")
            + f", following error of the nominal twin up to {length_text(self.fe_expected_max_m)}"
        )
        out = [head]
        if not self.position_evidence:
            out.append(
                "the position channel carries no evidence: the following error is below the "
                "resolution, so set minus actual shows the rounding; it is not fitted or tested"
            )
        out += [u.line() for u in self.unseen]
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
            "its signature on the position (microns) is below the record's resolution "
            f"{length_text(q)}"
        )
        unseen += [Unseen(name=e, reason=why) for e in POSITION_EFFECTS]
    unseen += _fast_effects(run, twin, speed[moving], h)
    unseen += [u for u in _uncarried(run, twin) if u.name not in {v.name for v in unseen}]
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
        notes=tuple(n for n in (mixed_steps(raw),) if n is not None),
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


def _uncarried(run: MeasuredRun, twin: Twin) -> list[Unseen]:
    """Effects the model has nothing to carry and the ranking cannot even weigh in this record,
    said rather than left out in silence: the inverter's dead time in a model without an
    Inverter (an effort source behind an ideal current loop) on a record without the drive's
    q-current (its signature is a function of the current's sign)."""
    if twin.doc.of_type("Inverter") or run.signals.get("current_q_A") is not None:
        return []
    if expandable(twin.doc):  # its drive's data sheet gives the stage (analysis.drive_stage)
        return []
    return [
        Unseen(
            name="dead_time",
            reason="the model drives its motor through an ideal current loop (no Inverter): the "
            "inverter's dead time, volts its current loop makes up after every reversal of the "
            "phase currents (the actual current dips for a few ms there), has nothing to act "
            "on; a model with an Inverter and its current loop can name it",
            by_model=True,
        )
    ]


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


def too_small(vis: Visibility, named: list[str], ranking: list[Candidate]) -> list[Unseen]:
    """Visible effects the search did not name although their signature shows, said: a viscous
    friction whose signature explains some of the effort residual at the final model (the
    last ranking) but less than the MIN_EXPLAINED an effect must remove to be named (on a
    1 mm, 10 Hz record the residual is mostly the rounding's, through the twin's inertia, and a
    small viscous excess drowns in it), with its share and the excess its weight suggests (a
    low estimate: the sliding friction and the weight take part of it)."""
    from feed_twin.analysis.significance import MIN_EXPLAINED

    out = []
    for cand in ranking:
        if cand.name != "viscous_friction" or cand.name in named + list(vis.unseen_names):
            continue
        share = cand.support_fraction or cand.explained_fraction
        if not 0.0 < share < MIN_EXPLAINED:
            continue
        out.append(
            Unseen(
                name=cand.name,
                reason=f"not named: its signature explains {100 * share:.2g} % of the effort "
                f"residual left (an excess of about {abs(cand.force('v')):.2g} N s/m over the "
                f"model's), under the {100 * MIN_EXPLAINED:g} % an effect must remove: too "
                "small against this record's rounding",
            )
        )
    return out


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
    "force_constant_correlation",
    "position_resolution",
    "resolution",
    "smooth_staircases",
    "too_small",
    "unresolved",
    "with_floor",
]
