"""Align a measurement with a simulation and measure how far apart they are.

Alignment estimates two numbers:
- the time shift tau [s] such that y_meas(t) ~ y_ref(t - tau), from the peak of the
  cross-correlation of the two signals' derivatives (derivatives, so that a ramp or an offset does
  not dominate), refined below one sample by fitting a parabola through the peak and its two
  neighbours;
- the position offset [m], the median of the difference after the shift (a median, so that the
  transients of a few moves do not bias it).

Metrics follow the issue's definitions: the following-error deviation `e_meas - e_sim` (with
e = commanded - measured position, this equals `x_sim - x_meas`) as RMS and maximum, and the
relative error `100 * ||y - y_sim|| / ||y||` in percent for position and effort, and, when the
record has the current controller's q-axis voltage, the RMS of its residual (the channel in
which an inverter dead time shows; analysis.effects).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import minimize_scalar


@dataclass(frozen=True, kw_only=True)
class Alignment:
    time_shift_s: float  # [s] the measurement lags the reference by this much (>0: later)
    position_offset_m: float  # [m] measured minus reference position after the shift
    correlation: float  # [1] normalised cross-correlation at the peak, 1 = identical shape


def estimate_time_shift(
    t_s: np.ndarray, y_meas: np.ndarray, y_ref: np.ndarray, *, max_shift_s: float
) -> tuple[float, float]:
    """Time shift tau with y_meas(t) ~ y_ref(t - tau) and the normalised peak correlation.

    Both signals share the uniform time base `t_s`. The search is limited to |tau| <= max_shift_s.
    """
    t_s = np.asarray(t_s, dtype=float)
    h = float((t_s[-1] - t_s[0]) / (len(t_s) - 1))
    a = np.diff(np.asarray(y_meas, dtype=float))
    b = np.diff(np.asarray(y_ref, dtype=float))
    a = a - a.mean()
    b = b - b.mean()
    norm = float(np.sqrt(np.dot(a, a) * np.dot(b, b)))
    if norm == 0.0:
        raise ValueError("estimate_time_shift: a signal is constant; no shift can be estimated")
    n = len(a)
    max_lag = max(1, min(n // 2, int(np.ceil(max_shift_s / h))))
    size = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.fft.rfft(a, size) * np.conj(np.fft.rfft(b, size)), size)
    # index i holds lag i for i >= 0 and lag i - size for negative lags
    lags = np.arange(-max_lag, max_lag + 1)
    cross = full[lags % size]
    corr = cross / norm
    # mean squared mismatch over the overlap of each lag: energies from cumulative sums, so a
    # broad correlation peak of slow signals is not pulled towards zero lag by the overlap
    ca = np.concatenate(([0.0], np.cumsum(a * a)))
    cb = np.concatenate(([0.0], np.cumsum(b * b)))
    pos = np.maximum(lags, 0)
    neg = np.maximum(-lags, 0)
    energy_a = ca[n - neg] - ca[pos]
    energy_b = cb[n - pos] - cb[neg]
    ssd = (energy_a + energy_b - 2.0 * cross) / (n - np.abs(lags))
    lag = int(lags[int(np.argmin(ssd))])

    # below one sample: minimise the mean squared difference of a(k) and b(k - tau) with b
    # interpolated, over the samples that overlap for every tau in the bracket
    k = np.arange(n, dtype=float)
    inner = slice(abs(lag) + 2, n - abs(lag) - 2)

    def mismatch(tau: float) -> float:
        shifted = np.interp(k[inner] - tau, k, b)
        return float(np.mean((a[inner] - shifted) ** 2))

    best = minimize_scalar(
        mismatch, bounds=(lag - 1.0, lag + 1.0), method="bounded", options={"xatol": 1e-4}
    )
    tau = float(best.x)
    return tau * h, float(corr[lag + max_lag])


def shift_signal(t_s: np.ndarray, y: np.ndarray, shift_s: float) -> np.ndarray:
    """y(t - shift) on the same time base, linear interpolation, ends held."""
    return np.interp(np.asarray(t_s) - shift_s, t_s, y)


def align(
    t_s: np.ndarray, x_meas: np.ndarray, x_ref: np.ndarray, *, max_shift_s: float = 0.5
) -> Alignment:
    """Time shift and position offset of a measured position against a reference position."""
    shift, corr = estimate_time_shift(t_s, x_meas, x_ref, max_shift_s=max_shift_s)
    offset = float(np.median(np.asarray(x_meas) - shift_signal(t_s, x_ref, shift)))
    return Alignment(time_shift_s=shift, position_offset_m=offset, correlation=corr)


def resample(t_src: np.ndarray, y: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Linear resampling onto a common time base; outside the source range the ends are held."""
    return np.interp(t_dst, t_src, y)


def relative_error_pct(y: np.ndarray, y_sim: np.ndarray) -> float:
    """100 * ||y - y_sim|| / ||y|| (the EMPS benchmark's measure)."""
    y = np.asarray(y, dtype=float)
    ref = float(np.linalg.norm(y))
    if ref == 0.0:
        raise ValueError("relative_error_pct: the measured signal is all zeros")
    return 100.0 * float(np.linalg.norm(y - np.asarray(y_sim, dtype=float))) / ref


@dataclass(frozen=True, kw_only=True)
class Metrics:
    """How far the twin is from the measurement on one run."""

    fe_dev_rms_m: float  # [m] RMS of following-error deviation e_meas - e_sim
    fe_dev_max_m: float  # [m] largest |e_meas - e_sim|
    pos_rel_err_pct: float  # [%] 100 ||x - x_sim|| / ||x||
    effort_rel_err_pct: float | None  # [%] same for the drive effort, when measured
    effort_rms: float | None  # [effort_unit] RMS of the effort residual
    samples: int
    voltage_q_rms_V: float | None = None  # [V] RMS of the commanded q-voltage residual
    effort_unit: str | None = None  # "N", "N m" or "A": the measured effort's own unit

    def as_dict(self) -> dict[str, float | int | None]:
        return asdict(self)


def compute_metrics(
    x_meas: np.ndarray,
    x_sim: np.ndarray,
    effort_meas: np.ndarray | None = None,
    effort_sim: np.ndarray | None = None,
    voltage_meas: np.ndarray | None = None,
    voltage_sim: np.ndarray | None = None,
    *,
    effort_unit: str | None = None,
) -> Metrics:
    """Metrics between measured and simulated position (effort, q-voltage) on one time base."""
    dev = np.asarray(x_sim, dtype=float) - np.asarray(x_meas, dtype=float)
    voltage_rms = None
    if voltage_meas is not None and voltage_sim is not None:
        du = np.asarray(voltage_meas, dtype=float) - np.asarray(voltage_sim, dtype=float)
        voltage_rms = float(np.sqrt(np.mean(du**2)))
    effort_rel = effort_rms = None
    if effort_meas is not None and effort_sim is not None:
        effort_rel = relative_error_pct(effort_meas, effort_sim)
        effort_rms = float(np.sqrt(np.mean((np.asarray(effort_meas) - effort_sim) ** 2)))
    return Metrics(
        fe_dev_rms_m=float(np.sqrt(np.mean(dev**2))),
        fe_dev_max_m=float(np.max(np.abs(dev))),
        pos_rel_err_pct=relative_error_pct(x_meas, x_sim),
        effort_rel_err_pct=effort_rel,
        effort_rms=effort_rms,
        samples=len(dev),
        voltage_q_rms_V=voltage_rms,
        effort_unit=None if effort_rms is None else effort_unit,
    )
