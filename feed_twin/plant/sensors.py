"""Sensors the drive samples once per base tick: encoder, linear scale, phase-current ADC.

Each writes its MEAS_* slots (feed_twin.core.signals) at a sample instant; the engine delays
the sample by `delay_ticks` base periods before the controller sees it. A delay d = n + f
(n whole, 0 <= f < 1) reads the ring of samples by linear interpolation between the samples
n and n + 1 ticks back, y = y[k-n] + f (y[k-n-1] - y[k-n]) (`delay_taps`): the first-order hold
of the sampled signal, exact for a ramp. A sine of frequency w through it keeps the lag
w d h exactly where f = 0 or 1/2 and otherwise lags by it within the hold's small phase error,
with the gain |1 - f + f e^{-j w h}| <= 1 (tests/test_sensor_fractional_delay.py); the noise of an
interpolated current sample is smaller by sqrt((1-f)^2 + f^2).
- Encoder on a rotational flange: theta = floor(phi / q) * q with q = 2*pi / counts_per_rev
  (an incremental count, so it truncates towards -inf like a counter does).
- LinearScale on a translational flange: x = floor(s / q) * q with q = resolution.
- CurrentSensor on the ac3 node: for each phase x in a, b, c, y = gain*i_x + offset + offset_x
  + noise_std*n (n standard normal, seeded: see feed_twin.plant.noise), clipped to the ADC range
  [-range_A, range_A) and rounded to the ADC step 2*range_A / 2^adc_bits. The common `offset`
  cancels in the Clarke transform; per-phase offsets do not: they give a measured i_alpha,
  i_beta offset of (2/3)(o_a - (o_b + o_c)/2), (o_b - o_c)/sqrt(3), which the rotating Park
  transform turns into a d/q ripple once per electrical revolution (a torque ripple in closed
  loop).
Ports: `flange` (rotational or translational, reads only) or `ac` (ac3, reads the currents).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from feed_twin.core.arrays import FloatArray
from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter, SlotSpec
from feed_twin.plant.effect_api import (
    Document,
    Edit,
    Effect,
    FreeParameter,
    Motion,
    Report,
    Weights,
    effort_rate,
    first_of,
    make_edit,
    motor_angle,
    slot_reader,
)

# the engine keeps the last MAX_DELAY_TICKS + 1 samples (sim.kernel.RING, a power of 2: the C
# kernel's modulo is a mask): 15.75 ms at the 0.25 ms tick of a drive's velocity loop. With 16
# kept a truth machine's 4 ms feedback delay was fitted as the 2 ms at the searched grid's edge
MAX_DELAY_TICKS = 63
DELAY_RING = MAX_DELAY_TICKS + 1  # the samples a delay reads from: tick k and 63 before it
# the sample delays the workflow searches for measurement_delay first: at least this many ticks
# and this long [s]; widened while the best lies at the grid's edge (analysis.trials), up to
# MAX_DELAY_TICKS
SEARCHED_DELAY_TICKS = 8
SEARCHED_DELAY_S = 5e-3


@njit(error_model="numpy", forceinline=True)
def quantize_floor(value: float, step: float) -> float:
    return math.floor(value * (1.0 / step)) * step  # the loop hoists 1/step


@njit(error_model="numpy", forceinline=True)
def adc(value: float, step: float, full_scale: float) -> float:
    clipped = min(max(value, -full_scale), full_scale - step)
    return math.floor(clipped * (1.0 / step) + 0.5) * step  # the loop hoists 1/step


@njit(error_model="numpy", forceinline=True)
def delay_taps(delay: float, k: int) -> tuple[int, int, float]:
    """The ring slots of the samples a delay of `delay` base periods reads at tick k (the
    newer, n = floor(delay) ticks back, and the older, n + 1 back; both clamped to tick 0: the
    first sample is held before the record) and the older one's weight, delay - n."""
    whole = int(delay)
    newer = k - min(whole, k)
    older = k - min(whole + 1, k)
    return newer % DELAY_RING, older % DELAY_RING, delay - whole


def _check_delay(delay_ticks: float) -> None:
    if not (math.isfinite(delay_ticks) and 0.0 <= delay_ticks <= MAX_DELAY_TICKS):
        raise ValueError(f"delay_ticks = {delay_ticks!r}: must lie in [0, {MAX_DELAY_TICKS}]")


def _position_sensors(doc: Document) -> list[str]:
    sensors = doc.of_type(Encoder.TYPE) + doc.of_type(LinearScale.TYPE)
    if not sensors:
        raise LookupError("the model has no Encoder or LinearScale")
    return sensors


def _loop_sensors(doc: Document) -> list[str]:
    """The position sensors the loops read: the motor encoders (the speed), and the linear
    scales where the position loop is closed on one. In a semi-closed loop the scale only
    records, and a delay of the loops' measurement leaves the record's position on time (the
    scale delayed with the encoder shifted the twin's recorded position: a 1-4 ms feedback
    delay of the truth machine was named a command or position delay)."""
    controller: dict[str, Any] = doc.data.get("controller") or {}
    position: dict[str, Any] = controller.get("position") or {}
    feedback = position.get("feedback")
    encoders = doc.of_type(Encoder.TYPE)
    if encoders and feedback == "motor_encoder":
        return encoders
    return _position_sensors(doc)


def _delay_edit(doc: Document, cand: Weights) -> Edit:
    """One sample delay for every position sensor the loops read, searched over whole base
    periods, then refined between the best one's neighbours (a fraction of a tick is
    interpolated: a real trace's delay is no multiple of the twin's tick)."""
    del cand
    slots = tuple(f"{s}.delay_ticks" for s in _loop_sensors(doc))
    name = "sensors.delay_ticks"
    doc = doc.tie(name, slots)
    period = doc.base_period()
    own = [
        FreeParameter(name=name, initial=doc.get(name), scale=1.0, lower=0.0, upper=MAX_DELAY_TICKS)
    ]
    report: Report = {"delay_ticks": lambda v: v[name], "delay_s": lambda v: v[name] * period}
    # searched, not differentiated: the cost has a kink at each whole tick (the interpolation
    # weights are piecewise linear in the delay), where finite differences mislead
    ticks = math.ceil(SEARCHED_DELAY_S / period - 1e-9)
    reach = min(MAX_DELAY_TICKS, max(SEARCHED_DELAY_TICKS, ticks))
    grid = tuple(float(k) for k in range(reach + 1))
    return make_edit(doc, own, report, interacts=False, grid=grid, refine=True)


def _delay_truth(doc: Document, p: Mapping[str, float]) -> Document:
    """The loops' sensors `delay_ticks` late, or `delay_s` (in base periods, a fraction too)."""
    ticks = p["delay_ticks"] if "delay_ticks" in p else p["delay_s"] / doc.base_period()
    for name in _loop_sensors(doc):
        doc = doc.set(f"{name}.delay_ticks", ticks)
    return doc


@dataclass(frozen=True, kw_only=True)
class Encoder(Component):
    TYPE = "Encoder"
    PORTS = {"flange": "rotational"}
    COMPUTED_SLOTS = {"step": SlotSpec(unit="rad", low=0.0, low_open=True)}  # 2 pi / counts
    EFFECTS = (
        Effect(
            name="measurement_delay",
            domain="effort",
            words="the loop acts on a position measured late: the effort follows the twin's "
            "effort shifted in time (sensor sample delay, slow fieldbus)",
            parameters="delay_ticks (and LinearScale.delay_ticks)",
            needs=("effort_sim",),
            signature=effort_rate,
            edit=_delay_edit,
            truth=_delay_truth,
        ),
    )

    counts_per_rev: int  # counts per revolution after quadrature decoding
    delay_ticks: float  # sample delay in base periods, fractions interpolated [1]

    def __post_init__(self) -> None:
        if self.counts_per_rev < 1:
            raise ValueError(f"counts_per_rev = {self.counts_per_rev!r}: must be >= 1")
        _check_delay(self.delay_ticks)

    def slots(self) -> dict[str, float]:
        return {"step": 2.0 * math.pi / self.counts_per_rev, "delay_ticks": float(self.delay_ticks)}

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "sense":
            phi, _ = g.across("flange")
            g.meas(
                "MEAS_THETA_ENC_RAD",
                f"quantize_floor({phi}, {g.p('step')})",
                delay=g.p("delay_ticks"),
            )


@dataclass(frozen=True, kw_only=True)
class LinearScale(Component):
    TYPE = "LinearScale"
    PORTS = {"flange": "translational"}

    resolution: float  # measuring step [m]
    delay_ticks: float  # sample delay in base periods, fractions interpolated [1]

    def __post_init__(self) -> None:
        require_positive("resolution", self.resolution)
        _check_delay(self.delay_ticks)

    def emit(self, stage: str, g: Emitter) -> None:
        if stage == "sense":
            s, _ = g.across("flange")
            g.meas(
                "MEAS_X_SCALE_M",
                f"quantize_floor({s}, {g.p('resolution')})",
                delay=g.p("delay_ticks"),
            )


def _electrical(m: Motion) -> dict[str, FloatArray]:
    assert m.pole_pairs is not None
    theta = m.pole_pairs * motor_angle(m)
    return {"sin": np.sin(theta), "cos": np.cos(theta)}


def _offset_edit(doc: Document, cand: Weights) -> Edit:
    """The three per-phase offsets of the CurrentSensor are fitted.

    The offsets read as alpha/beta errors (2/3)(o_a - (o_b + o_c)/2), (o_b - o_c)/sqrt(3) (a
    part common to the three phases cancels there); the current loop makes the true i_q differ
    from the measured by -q = alpha sin(theta_e) - beta cos(theta_e), and the velocity loop
    adds that back to its i_q command, so the effort residual is about -alpha sin + beta cos:
    the (sin, cos) weights (s, c) give the initial guess alpha = -s, beta = c with no common
    part. The common part is fitted too: the drive's dead-time compensation switches on the
    sign of each measured phase current, so a phase offset also shifts where that happens.
    """
    name = first_of(doc, CurrentSensor.TYPE, "whose phase offsets could be fitted")
    params = doc.component(name)["params"]
    alpha, beta = -cand.coefficients.get("sin", 0.0), cand.coefficients.get("cos", 0.0)
    guesses = (alpha, -0.5 * alpha + 0.5 * math.sqrt(3.0) * beta)
    guesses += (-guesses[0] - guesses[1],)
    # scaled by the ADC full scale: the finite-difference step (1e-3 of the scale) is then about
    # two counts of a 12-bit converter, large enough to average over the loop's sharp local
    # sensitivity at slow moves (stick-slip), small next to the offsets (the response is
    # close to linear in them)
    scale = float(params["range_A"])
    slots = tuple(f"{name}.offset_{x}" for x in "abc")
    for slot, guess in zip(slots, guesses, strict=True):
        doc = doc.set(slot, float(params.get(slot.split(".")[1], 0.0)) + guess)
    own = [FreeParameter(name=slot, initial=doc.get(slot), scale=scale) for slot in slots]
    report: Report = {f"{slot.split('.')[1]}_A": slot_reader(slot) for slot in slots}
    return make_edit(doc, own, report, interacts=False)


def _offset_truth(doc: Document, p: Mapping[str, float]) -> Document:
    name = first_of(doc, CurrentSensor.TYPE, "whose phase offsets could be fitted")
    for phase in ("a", "b", "c"):
        key = f"offset_{phase}_A"
        if key in p:
            doc = doc.set(f"{name}.offset_{phase}", p[key])
    return doc


@dataclass(frozen=True, kw_only=True)
class CurrentSensor(Component):
    TYPE = "CurrentSensor"
    PORTS = {"ac": "ac3"}
    COMPUTED_SLOTS = {"step": SlotSpec(unit="A", low=0.0, low_open=True)}  # ADC quantum
    EFFECTS = (
        Effect(
            name="current_offset",
            domain="effort",
            words="a force ripple once per electrical revolution: an offset in a phase-current "
            "measurement",
            parameters="offset_a, offset_b, offset_c",
            needs=("lead_m", "pole_pairs"),
            signature=_electrical,
            edit=_offset_edit,
            truth=_offset_truth,
        ),
    )

    gain: float  # sensor gain error factor (1 = ideal) [-]
    offset: float  # offset [A]
    noise_std: float  # white-noise standard deviation per sample [A]
    adc_bits: int  # ADC resolution [bit]
    range_A: float  # ADC full scale, +/- [A]
    delay_ticks: float  # sample delay in base periods, fractions interpolated [1]
    offset_a: float = 0.0  # offset of phase a alone, on top of `offset` [A]
    offset_b: float = 0.0  # offset of phase b alone [A]
    offset_c: float = 0.0  # offset of phase c alone [A]

    def __post_init__(self) -> None:
        require_positive("gain", self.gain)
        require_finite("offset", self.offset)
        for name in ("offset_a", "offset_b", "offset_c"):
            require_finite(name, getattr(self, name))
        require_nonnegative("noise_std", self.noise_std)
        if not 2 <= self.adc_bits <= 24:
            raise ValueError(f"adc_bits = {self.adc_bits!r}: must lie in [2, 24]")
        require_positive("range_A", self.range_A)
        _check_delay(self.delay_ticks)

    def slots(self) -> dict[str, float]:
        return {
            "gain": self.gain,
            "offset": self.offset,
            "noise_std": self.noise_std,
            "step": 2.0 * self.range_A / 2.0**self.adc_bits,
            "range_A": self.range_A,
            "delay_ticks": float(self.delay_ticks),
            "offset_a": self.offset_a,
            "offset_b": self.offset_b,
            "offset_c": self.offset_c,
        }

    def emit(self, stage: str, g: Emitter) -> None:
        if stage != "sense":
            return
        for n, x in enumerate(("a", "b", "c")):
            raw = (
                f"{g.p('gain')} * {g.el('ac', f'i_{x}')} + {g.p('offset')}"
                f" + {g.p(f'offset_{x}')} + {g.noise(n, g.p('noise_std'))}"
            )
            g.meas(
                f"MEAS_I_{x.upper()}",
                f"adc({raw}, {g.p('step')}, {g.p('range_A')})",
                delay=g.p("delay_ticks"),
            )
