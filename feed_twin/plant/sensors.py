"""Sensors the drive samples once per base tick: encoder, linear scale, phase-current ADC.

Each writes its MEAS_* slots (feed_twin.core.signals) at a sample instant; the engine delays
the sample by `delay_ticks` whole base periods before the controller sees it.
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
from dataclasses import dataclass

from numba import njit

from feed_twin.core.validate import require_finite, require_nonnegative, require_positive
from feed_twin.plant.component import Component, Emitter

MAX_DELAY_TICKS = 15  # the engine keeps the last 16 samples


@njit(error_model="numpy", forceinline=True)
def quantize_floor(value: float, step: float) -> float:
    return math.floor(value * (1.0 / step)) * step  # the loop hoists 1/step


@njit(error_model="numpy", forceinline=True)
def adc(value: float, step: float, full_scale: float) -> float:
    clipped = min(max(value, -full_scale), full_scale - step)
    return math.floor(clipped * (1.0 / step) + 0.5) * step  # the loop hoists 1/step


def _check_delay(delay_ticks: int) -> None:
    if not 0 <= delay_ticks <= MAX_DELAY_TICKS:
        raise ValueError(f"delay_ticks = {delay_ticks!r}: must lie in [0, {MAX_DELAY_TICKS}]")


@dataclass(frozen=True, kw_only=True)
class Encoder(Component):
    TYPE = "Encoder"
    PORTS = {"flange": "rotational"}

    counts_per_rev: int  # counts per revolution after quadrature decoding
    delay_ticks: int  # sample delay in base periods

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
    delay_ticks: int  # sample delay in base periods

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


@dataclass(frozen=True, kw_only=True)
class CurrentSensor(Component):
    TYPE = "CurrentSensor"
    PORTS = {"ac": "ac3"}

    gain: float  # sensor gain error factor (1 = ideal) [-]
    offset: float  # offset [A]
    noise_std: float  # white-noise standard deviation per sample [A]
    adc_bits: int  # ADC resolution [bit]
    range_A: float  # ADC full scale, +/- [A]
    delay_ticks: int  # sample delay in base periods
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
