"""Where do twin and machine disagree? Residual statistics along the axes an engineer looks at.

Given a residual r(t) (effort or position) and the measured motion, this module groups r by
- time window (does it grow? a thermal drift does),
- direction of motion (+, -, standstill: friction and backlash change sign with it),
- speed bin (viscous grows with speed, Stribeck lives near zero),
- position along the screw (stiffness and lead errors depend on it),
- motor-angle and screw-angle phase (cogging repeats with the rotor, lead errors with the screw),
and computes its amplitude spectrum (Welch). Each grouping returns the mean and RMS per bin, so a
report can say "the effort residual is +19 N when moving forward and -21 N when moving back".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

STANDSTILL_FRACTION = 0.02  # |v| below this share of the peak speed counts as standstill


@dataclass(frozen=True, kw_only=True)
class Bins:
    """Residual statistics per bin of one quantity."""

    quantity: str  # what the bins are of, e.g. "velocity [m/s]"
    edges: tuple[float, ...]  # bin edges, len = bins + 1 (labels for categorical groupings)
    labels: tuple[str, ...]
    count: tuple[int, ...]
    mean: tuple[float, ...]
    rms: tuple[float, ...]

    def as_dict(self) -> dict[str, object]:
        return {
            "quantity": self.quantity,
            "labels": list(self.labels),
            "count": list(self.count),
            "mean": list(self.mean),
            "rms": list(self.rms),
        }


@dataclass(frozen=True, kw_only=True)
class Spectrum:
    frequency_hz: np.ndarray
    amplitude: np.ndarray  # amplitude spectral density of the residual [unit/sqrt(Hz)]
    peaks_hz: tuple[float, ...]  # the strongest peaks, strongest first


@dataclass(frozen=True, kw_only=True)
class Location:
    """Everything `locate` found about one residual."""

    residual_name: str
    unit: str
    rms: float
    by_time: Bins
    by_direction: Bins
    by_speed: Bins
    by_position: Bins
    by_motor_phase: Bins | None
    by_screw_phase: Bins | None
    spectrum: Spectrum

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"residual": self.residual_name, "unit": self.unit}
        out["rms"] = self.rms
        for key in ("by_time", "by_direction", "by_speed", "by_position"):
            out[key] = getattr(self, key).as_dict()
        for key in ("by_motor_phase", "by_screw_phase"):
            value = getattr(self, key)
            out[key] = None if value is None else value.as_dict()
        out["spectrum_peaks_hz"] = list(self.spectrum.peaks_hz)
        return out

    def summary(self) -> list[str]:
        """Plain-words findings, strongest contrast first."""
        lines = []
        d = self.by_direction
        by_label = dict(zip(d.labels, d.mean, strict=True))
        lines.append(
            f"{self.residual_name}: mean {by_label['forward']:+.4g} {self.unit} moving forward, "
            f"{by_label['backward']:+.4g} {self.unit} moving back, "
            f"{by_label['standstill']:+.4g} {self.unit} at standstill"
        )
        t = self.by_time
        lines.append(
            f"{self.residual_name}: RMS per time window from {t.rms[0]:.4g} to {t.rms[-1]:.4g} "
            f"{self.unit} (first to last of {len(t.rms)})"
        )
        s = self.by_speed
        j = int(np.nanargmax(np.abs(s.mean)))
        lines.append(
            f"{self.residual_name}: largest mean {s.mean[j]:+.4g} {self.unit} "
            f"at speed {s.labels[j]} m/s"
        )
        if self.spectrum.peaks_hz:
            peaks = ", ".join(f"{f:.3g}" for f in self.spectrum.peaks_hz[:3])
            lines.append(f"{self.residual_name}: spectral peaks at {peaks} Hz")
        return lines


def _binned(
    values: np.ndarray, residual: np.ndarray, edges: np.ndarray, quantity: str, fmt: str
) -> Bins:
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    count = np.bincount(idx, minlength=len(edges) - 1)
    sums = np.bincount(idx, weights=residual, minlength=len(edges) - 1)
    squares = np.bincount(idx, weights=residual**2, minlength=len(edges) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, sums / np.maximum(count, 1), np.nan)
        rms = np.where(count > 0, np.sqrt(squares / np.maximum(count, 1)), np.nan)
    labels = tuple(
        f"{fmt.format(lo)}..{fmt.format(hi)}" for lo, hi in zip(edges[:-1], edges[1:], strict=True)
    )
    return Bins(
        quantity=quantity,
        edges=tuple(float(e) for e in edges),
        labels=labels,
        count=tuple(int(c) for c in count),
        mean=tuple(float(m) for m in mean),
        rms=tuple(float(r) for r in rms),
    )


def direction(v: np.ndarray) -> np.ndarray:
    """+1 forward, -1 backward, 0 standstill (|v| under STANDSTILL_FRACTION of the peak)."""
    v = np.asarray(v, dtype=float)
    limit = STANDSTILL_FRACTION * float(np.max(np.abs(v)))
    return np.where(v > limit, 1.0, np.where(v < -limit, -1.0, 0.0))


def spectrum(residual: np.ndarray, sample_period_s: float, *, peaks: int = 5) -> Spectrum:
    """Welch amplitude spectral density and its strongest local maxima (DC excluded)."""
    r = np.asarray(residual, dtype=float)
    nperseg = int(min(len(r), 4096))
    f, pxx = sps.welch(r - r.mean(), fs=1.0 / sample_period_s, nperseg=nperseg)
    asd = np.sqrt(pxx)
    found, _ = sps.find_peaks(asd[1:])
    found = found + 1
    order = found[np.argsort(asd[found])[::-1]][:peaks]
    return Spectrum(frequency_hz=f, amplitude=asd, peaks_hz=tuple(float(f[i]) for i in order))


def locate(
    t_s: np.ndarray,
    residual: np.ndarray,
    x_m: np.ndarray,
    v_m_s: np.ndarray,
    *,
    residual_name: str,
    unit: str,
    lead_m: float | None = None,
    pole_pairs: int | None = None,
    windows: int = 10,
    bins: int = 8,
) -> Location:
    """Group a residual by time, direction, speed, position and angle phases; add its spectrum.

    `lead_m` [m/rev] turns table travel into screw angle (and motor angle for a direct drive);
    `pole_pairs` turns the motor angle into electrical phase. Without them the phase groupings
    are None.
    """
    t = np.asarray(t_s, dtype=float)
    r = np.asarray(residual, dtype=float)
    x = np.asarray(x_m, dtype=float)
    v = np.asarray(v_m_s, dtype=float)
    h = float((t[-1] - t[0]) / (len(t) - 1))
    by_time = _binned(t, r, np.linspace(t[0], t[-1], windows + 1), "time [s]", "{:.3g}")
    dirn = direction(v)
    by_dir = _binned(dirn, r, np.array([-1.5, -0.5, 0.5, 1.5]), "direction", "{:.0f}")
    by_dir = Bins(
        quantity="direction of motion",
        edges=by_dir.edges,
        labels=("backward", "standstill", "forward"),
        count=by_dir.count,
        mean=by_dir.mean,
        rms=by_dir.rms,
    )
    vmax = float(np.max(np.abs(v)))
    by_speed = _binned(
        v, r, np.linspace(-vmax, vmax, 2 * (bins // 2) + 1), "velocity [m/s]", "{:+.3g}"
    )
    by_pos = _binned(
        x, r, np.linspace(x.min(), x.max() + 1e-12, bins + 1), "position [m]", "{:.4g}"
    )
    motor = screw = None
    if lead_m is not None:
        theta = 2.0 * math.pi * x / lead_m
        phase_edges = np.linspace(0.0, 360.0, 13)
        screw = _binned(
            np.degrees(np.mod(theta, 2 * math.pi)), r, phase_edges, "screw angle [deg]", "{:.0f}"
        )
        if pole_pairs is not None:
            theta_el = np.mod(pole_pairs * theta, 2 * math.pi)
            motor = _binned(
                np.degrees(theta_el), r, phase_edges, "electrical angle [deg]", "{:.0f}"
            )
    return Location(
        residual_name=residual_name,
        unit=unit,
        rms=float(np.sqrt(np.mean(r**2))),
        by_time=by_time,
        by_direction=by_dir,
        by_speed=by_speed,
        by_position=by_pos,
        by_motor_phase=motor,
        by_screw_phase=screw,
        spectrum=spectrum(r, h),
    )
