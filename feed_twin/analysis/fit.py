"""Simulation-based (output-error) least squares with the engine's batch mode.

The cost is the closed-loop mismatch between the measured run and the twin driven by the same
command and known disturbances,

    J(theta) = sum_k [(e_meas(k) - e_sim(k; theta)) / s_e]^2
               + [(x_meas(k) - x_sim(k; theta)) / s_x]^2
               + [(u_meas(k) - u_sim(k; theta)) / s_u]^2

over a decimated time base, with e the drive effort, x the measured position and u the q-axis
voltage the current controller commands (only when the record carries it: the one channel in
which an inverter's dead time shows, see analysis.effects). s_e, s_x and s_u are each channel's
noise level (analysis.channels: its residual RMS at the model of the current round, floored by
its sample noise), so a channel that one large effect explained keeps its say. scipy's
trust-region reflective solver minimises it; its Jacobian comes from forward differences
evaluated as ONE batch of P perturbed parameter sets, which is what the engine's batch mode is
for. A step whose simulation diverges returns a large finite residual, so the
solver backs off instead of failing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from feed_twin.plant.effect_api import FreeParameter

DIVERGED_RESIDUAL = 1e3  # residual entries (normalised) of a diverged simulation


@dataclass(frozen=True, kw_only=True, eq=False)
class SimOutputs:
    """Simulated signals of a batch: one row per parameter set (SI units)."""

    x_m: np.ndarray  # (N, T) position as the measurement system reports it
    effort: np.ndarray | None  # (N, T) drive effort in the measured effort's unit, or None
    ok: np.ndarray  # (N,) False where the simulation diverged
    voltage_q: np.ndarray | None = None  # (N, T) commanded q-axis voltage [V], or None


BatchSimulator = Callable[[np.ndarray], SimOutputs]  # params (N, P) -> outputs


@dataclass(frozen=True, kw_only=True, eq=False)
class FitResult:
    values: dict[str, float]
    cost_initial: float  # J at the initial values
    cost: float  # J at the result
    converged: bool
    message: str
    evaluations: int  # parameter sets simulated
    outputs: SimOutputs  # the simulation at the result


@dataclass(frozen=True, kw_only=True, eq=False)
class Measured:
    """The measured channels on the simulation's time base."""

    x_m: np.ndarray
    effort: np.ndarray | None
    scale_x: float  # [m] normalisation of the position channel
    scale_effort: float  # normalisation of the effort channel
    stride: int = 1  # use every stride-th sample
    start: int = 0  # the first sample that is evidence (Twin.first_evidence)
    voltage_q: np.ndarray | None = None  # [V] commanded q-axis voltage, when recorded
    scale_voltage: float = 1.0  # [V] normalisation of the voltage channel
    # the position's zero is not known (MeasuredRun.position_offset_free): the channel's mean
    # is a free constant, fitted with every simulation
    free_offset: bool = False
    # per-sample weight of the effort channel (0 where it is no evidence), None for all 1
    effort_weight: np.ndarray | None = None


def residual_parts(
    meas: Measured,
    x_sim: np.ndarray,
    effort_sim: np.ndarray | None,
    voltage_sim: np.ndarray | None = None,
) -> list[np.ndarray]:
    """Each channel's normalised residual: position, then effort and voltage where compared."""
    s = slice(meas.start, None, meas.stride)
    dx = meas.x_m[s] - x_sim[s]
    if meas.free_offset:
        dx = dx - float(np.mean(dx))
    parts = [dx / meas.scale_x]
    if meas.effort is not None and effort_sim is not None:
        de = (meas.effort[s] - effort_sim[s]) / meas.scale_effort
        parts.append(de if meas.effort_weight is None else de * meas.effort_weight[s])
    if meas.voltage_q is not None and voltage_sim is not None:
        parts.append((meas.voltage_q[s] - voltage_sim[s]) / meas.scale_voltage)
    return parts


def residual_vector(
    meas: Measured,
    x_sim: np.ndarray,
    effort_sim: np.ndarray | None,
    voltage_sim: np.ndarray | None = None,
) -> np.ndarray:
    return np.concatenate(residual_parts(meas, x_sim, effort_sim, voltage_sim))


def _row(signal: np.ndarray | None, row: int) -> np.ndarray | None:
    return None if signal is None else signal[row]


def cost_of(meas: Measured, out: SimOutputs, row: int = 0) -> float:
    if not out.ok[row]:
        return np.inf
    r = residual_vector(meas, out.x_m[row], _row(out.effort, row), _row(out.voltage_q, row))
    return float(np.dot(r, r))


def profile_cost(meas: Measured, out: SimOutputs, row: int = 0) -> float:
    """-2 log-likelihood (to a constant) with each channel's noise level unknown and taken at
    its estimate at this model, sum_c n_c log(RSS_c / n_c): a channel weighs by how much of its
    own residual a model removes, whatever the weights `meas` carries (J's s_x, s_e, set at
    the model before the effect). A sensor delay takes the position's residual from the
    delay's own 112 um RMS to 0.25 um (the truth machine's 1.125 ms): under J's weights set
    at 112 um a 4 % smaller effort residual outweighed a 50x larger position residual
    (trials.refined)."""
    if not out.ok[row]:
        return np.inf
    effort = _row(out.effort, row)
    parts = residual_parts(meas, out.x_m[row], effort, _row(out.voltage_q, row))
    counts = [float(len(part)) for part in parts]
    if meas.effort is not None and effort is not None and meas.effort_weight is not None:
        counts[1] = float(np.sum(meas.effort_weight[meas.start :: meas.stride] ** 2))
    return sum(
        n * np.log(max(float(np.dot(part, part)) / n, np.finfo(float).tiny))
        for part, n in zip(parts, counts, strict=True)
        if n > 0.0
    )


def fit(
    simulate: BatchSimulator,
    base: np.ndarray,
    index: dict[str, tuple[int, ...]],
    free: list[FreeParameter],
    meas: Measured,
    *,
    max_evaluations: int = 60,
) -> FitResult:
    """Fit the free parameters; the others stay at `base` (a full engine parameter vector).

    `index` maps a free parameter's name to the engine slots it sets (several for a tied
    parameter, e.g. one Coulomb force for both directions).
    """
    slots = [index[p.name] for p in free]
    scale = np.array([p.scale for p in free], dtype=float)
    is_log = np.array([p.log for p in free], dtype=bool)

    # the log map applies to the log parameters only: np.where would evaluate exp on a linear
    # parameter's z too (a stiffness of 1e9 N/m at scale 1 overflows) and then discard it
    def to_z(values: np.ndarray) -> np.ndarray:
        zs = values / scale
        with np.errstate(divide="ignore"):  # a log parameter's lower bound 0 maps to -inf
            zs[..., is_log] = np.log(np.maximum(values[..., is_log], 0.0) / scale[is_log])
        return zs

    def to_value(zs: np.ndarray) -> np.ndarray:
        values = zs * scale
        values[..., is_log] = np.exp(zs[..., is_log]) * scale[is_log]
        return values

    lower = to_z(np.array([p.lower for p in free], dtype=float))
    upper = to_z(np.array([p.upper for p in free], dtype=float))
    z0 = np.clip(to_z(np.array([p.initial for p in free], dtype=float)), lower, upper)
    counter = {"sets": 0}
    cache: dict[bytes, tuple[np.ndarray, SimOutputs]] = {}

    def params_of(zs: np.ndarray) -> np.ndarray:
        batch = np.repeat(base[None, :], len(zs), axis=0)
        values = to_value(zs)
        for j, group in enumerate(slots):
            for i in group:
                batch[:, i] = values[:, j]
        return batch

    def residuals_of(out: SimOutputs, n: int) -> list[np.ndarray]:
        rows = []
        for i in range(n):
            if out.ok[i]:
                r = residual_vector(meas, out.x_m[i], _row(out.effort, i), _row(out.voltage_q, i))
                rows.append(np.where(np.isfinite(r), r, DIVERGED_RESIDUAL))
            else:
                rows.append(None)
        length = next((len(r) for r in rows if r is not None), None)
        if length is None:
            length = len(residual_vector(meas, meas.x_m, meas.effort, meas.voltage_q))
        return [np.full(length, DIVERGED_RESIDUAL) if r is None else r for r in rows]

    def fun(z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in cache:
            out = simulate(params_of(z[None, :]))
            counter["sets"] += 1
            cache.clear()
            cache[key] = (residuals_of(out, 1)[0], out)
        return cache[key][0]

    def jac(z: np.ndarray) -> np.ndarray:
        r0 = fun(z)
        step = 1e-3 * np.maximum(np.abs(z), 1.0)
        # step inward at an upper bound so that every perturbed set stays feasible
        step = np.where(z + step > upper, -step, step)
        zs = z[None, :] + np.diag(step)
        out = simulate(params_of(zs))
        counter["sets"] += len(zs)
        rows = residuals_of(out, len(zs))
        return np.column_stack([(rows[i] - r0) / step[i] for i in range(len(zs))])

    r_init = fun(z0)
    cost_initial = float(np.dot(r_init, r_init))
    try:
        sol = least_squares(
            fun,
            z0,
            jac=jac,  # pyright: ignore[reportArgumentType]  scipy's hint omits the callable form
            bounds=(lower, upper),
            method="trf",
            x_scale="jac",
            max_nfev=max_evaluations,
            xtol=1e-6,
            ftol=1e-6,
        )
        z, converged, message = sol.x, bool(sol.status > 0), str(sol.message)
    except (ValueError, np.linalg.LinAlgError) as exc:
        z, converged, message = z0, False, f"least squares failed: {exc}"
    r = fun(z)
    cost = float(np.dot(r, r))
    out = cache[z.tobytes()][1]
    if not bool(out.ok[0]) or cost > cost_initial:
        # never hand back a worse model than the one we started from
        z, cost, converged = z0, cost_initial, False
        message = f"{message}; kept the initial values (the fit did not improve them)"
        fun(z)
        out = cache[z.tobytes()][1]
    values = {p.name: float(v) for p, v in zip(free, to_value(z), strict=True)}
    return FitResult(
        values=values,
        cost_initial=cost_initial,
        cost=cost,
        converged=converged,
        message=message,
        evaluations=counter["sets"],
        outputs=out,
    )
