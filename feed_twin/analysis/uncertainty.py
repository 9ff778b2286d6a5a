"""Confidence intervals and correlations of the fitted parameters, from the Jacobian at the optimum.

The fit minimises J = sum_c |r_c|^2, r_c each channel's residual divided by its noise level
(analysis.fit). Near the optimum r(theta + d) = r + S d, S the sensitivity of the normalised
residuals to the parameters, evaluated here by forward differences as ONE batch of the engine
(a row per parameter, and one at the optimum). The least-squares estimate's covariance is the
sandwich

    C = H^-1 M H^-1,   H = S^T S,   M = sum_c tau_c s_c^2 S_c^T S_c

with s_c^2 the variance of channel c's normalised residual and tau_c = n_c / n_eff,c its
integrated autocorrelation time (analysis.significance.effective_samples): a smooth residual
carries fewer independent observations than it has samples, and the interval widens by
sqrt(tau) accordingly. The interval of a reported parameter (a function of the fitted slots:
asymmetric friction's forward and backward coefficients) follows by the delta method.

What an interval does NOT hold: the bias of a model that lacks a law the machine has (its
residual is treated as noise, correlated as it is). Two parameters whose estimates are
correlated beyond CORRELATED (a mass and a torque constant, both scaling the acceleration's
force) are said: the record then fixes their combination, not each.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from feed_twin.analysis.fit import Measured, residual_vector
from feed_twin.analysis.significance import effective_samples
from feed_twin.analysis.twin import Drive, Twin
from feed_twin.plant.effect_api import FreeParameter

Z95 = 1.959963984540054  # two-sided 95 % quantile of the normal distribution
CORRELATED = 0.9  # |correlation| of two estimates above which the user is told
STEP = 1e-4  # relative finite-difference step of a parameter (of its scale where it is 0)


@dataclass(frozen=True, kw_only=True, eq=False)
class Sensitivity:
    """The normalised residuals at the optimum and their derivatives by the free parameters."""

    names: tuple[str, ...]  # free slots
    values: np.ndarray  # (p,) their values at the optimum
    r: np.ndarray  # (n,) normalised residuals, the channels one after the other
    S: np.ndarray  # (n, p) d r / d value
    blocks: dict[str, slice]  # channel -> its rows of r and S
    t_s: np.ndarray  # (n,) the time of each row
    simulations: int


def sensitivity(
    twin: Twin, drive: Drive, free: list[FreeParameter], meas: Measured, t_s: np.ndarray
) -> Sensitivity | None:
    """S at the twin's own parameters (the optimum); None if a simulation diverges."""
    names = tuple(p.name for p in free)
    values = np.array([twin.nominal[twin.index[n][0]] for n in names], dtype=float)
    steps = STEP * np.maximum(np.abs(values), np.array([p.scale for p in free]))
    upper = np.array([p.upper for p in free])
    steps = np.where(values + steps > upper, -steps, steps)  # inward at an upper bound
    batch = np.repeat(twin.nominal[None, :], len(names) + 1, axis=0)
    for j, name in enumerate(names):
        for i in twin.index[name]:
            batch[j + 1, i] = values[j] + steps[j]
    out = twin.simulate(drive, batch)
    if not bool(np.all(out.ok)):
        return None

    def row(k: int) -> np.ndarray:
        effort = None if out.effort is None else out.effort[k]
        voltage = None if out.voltage_q is None else out.voltage_q[k]
        return residual_vector(meas, out.x_m[k], effort, voltage)

    r = row(0)
    S = np.column_stack([(row(j + 1) - r) / steps[j] for j in range(len(names))])
    times = t_s[meas.start :: meas.stride]
    channels = ["position"]
    if meas.effort is not None and out.effort is not None:
        channels.append("effort")
    if meas.voltage_q is not None and out.voltage_q is not None:
        channels.append("voltage")
    m = len(times)
    blocks = {c: slice(k * m, (k + 1) * m) for k, c in enumerate(channels)}
    return Sensitivity(
        names=names,
        values=values,
        r=r,
        S=S,
        blocks=blocks,
        t_s=np.tile(times, len(channels)),
        simulations=len(batch),
    )


@dataclass(frozen=True, kw_only=True, eq=False)
class Estimates:
    """The free parameters' values with their covariance (module docstring)."""

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def correlation(self) -> np.ndarray:
        s = self.sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = self.covariance / np.outer(s, s)
        return np.clip(np.where(np.isfinite(rho), rho, 0.0), -1.0, 1.0)

    def correlated(self) -> list[tuple[str, str, float]]:
        """The pairs whose estimates are correlated beyond CORRELATED, strongest first."""
        rho = self.correlation()
        pairs = [
            (self.names[i], self.names[j], float(rho[i, j]))
            for i in range(len(self.names))
            for j in range(i + 1, len(self.names))
            if abs(rho[i, j]) > CORRELATED
        ]
        return sorted(pairs, key=lambda p: -abs(p[2]))

    def interval(
        self, of: Callable[[dict[str, float]], float], at: Mapping[str, float]
    ) -> tuple[float, float, float]:
        """(value, low, high) of a function of the free parameters (95 %, delta method); `at`
        gives every other name `of` reads."""
        free = dict(zip(self.names, map(float, self.values), strict=True))
        centre = float(of(_Overlay(at, free)))
        grad = np.zeros(len(self.names))
        for j, name in enumerate(self.names):
            h = STEP * max(abs(free[name]), math.sqrt(max(self.covariance[j, j], 0.0)), 1e-30)
            grad[j] = (float(of(_Overlay(at, free | {name: free[name] + h}))) - centre) / h
        half = Z95 * math.sqrt(max(float(grad @ self.covariance @ grad), 0.0))
        return centre, centre - half, centre + half


class _Overlay(dict):
    """`values`, falling back to `base` for every other name."""

    def __init__(self, base: Mapping[str, float], values: dict[str, float]) -> None:
        super().__init__(values)
        self.base = base

    def __missing__(self, name: str) -> float:
        return self.base[name]


def estimates(s: Sensitivity) -> Estimates:
    """The sandwich covariance of the least-squares estimate (module docstring)."""
    # in units of each column's norm: H of parameters of very different sizes (a stiffness of
    # 1e9 N/m beside a mass of 100 kg) is otherwise too ill-conditioned to invert in doubles
    norm = np.linalg.norm(s.S, axis=0)
    norm[norm == 0.0] = 1.0
    S_all = s.S / norm
    H = S_all.T @ S_all
    M = np.zeros_like(H)
    for rows in s.blocks.values():
        r, S = s.r[rows], S_all[rows]
        if len(r) < 3:
            continue
        tau = len(r) / max(effective_samples(r), 1.0)
        M += tau * float(np.mean(r**2)) * (S.T @ S)
    H_inv = np.linalg.pinv(H, hermitian=True)
    C = H_inv @ M @ H_inv
    C = 0.5 * (C + C.T) / np.outer(norm, norm)
    return Estimates(names=s.names, values=s.values, covariance=C)
