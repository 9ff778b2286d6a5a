"""Is the recorded effort counted against the twin's? Decided by fitting both signs.

A drive's trace may count its current against the motion (a Sinumerik 840D's does on some
axes). The workflow would then blame every effect but the sign, and fit an upward weight of
4074 N on a real record. A correlation threshold between the measured and the nominal twin's
effort does not see it when a weight or friction dominates the effort: the real record
correlated at -0.43. So both signs are fitted, each with what the nominal twin may lack and the
sign may not hide: the twin's effort at a free scale s >= 0 (a torque constant known only
roughly) plus a constant force, a sliding friction sign(v) and a viscous term v,

    measured = sign * s * effort_twin + c_0 + c_1 tanh(v / v_eps) + c_2 v,

and the sign is reversed when the reversed fit leaves less than 1 / REVERSED_FIT_RATIO of the
residual energy the fit as recorded leaves. The two fits differ only in the sign of the scale,
so the unconstrained least-squares scale's sign decides which one wins; the ratio says by how
much.
"""

from __future__ import annotations

import numpy as np

from feed_twin.analysis.fit import SimOutputs
from feed_twin.io.measured import EFFORT_UNITS, MeasuredDataError, MeasuredRun

# the reversed sign must leave less than half the residual energy of the sign as recorded
REVERSED_FIT_RATIO = 2.0
SPEED_EPS_SHARE = 0.002  # tanh's regularising speed as a share of the peak speed


def _free_terms(run: MeasuredRun) -> np.ndarray:
    """The columns the nominal twin may lack: a constant force, sliding friction, viscous."""
    v = np.gradient(run["pos_meas_m"], run.t_s)
    eps = max(SPEED_EPS_SHARE * float(np.max(np.abs(v))), 1e-12)
    return np.column_stack((np.ones_like(v), np.tanh(v / eps), v))


def _residual_energy(y: np.ndarray, columns: np.ndarray) -> float:
    coef, *_ = np.linalg.lstsq(columns, y, rcond=None)
    return float(np.sum((y - columns @ coef) ** 2))


def sign_fits(run: MeasuredRun, twin_effort: np.ndarray) -> tuple[float, float]:
    """(residual energy as recorded, with the sign reversed) of the fits of the module
    docstring [effort unit^2]."""
    y = run[run.effort_name or ""]
    free = _free_terms(run)
    full = np.column_stack((twin_effort, free))
    coef, *_ = np.linalg.lstsq(full, y, rcond=None)
    best = float(np.sum((y - full @ coef) ** 2))
    without = _residual_energy(y, free)  # the scale at its bound 0
    return (best, without) if coef[0] >= 0.0 else (without, best)


def check_effort_sign(run: MeasuredRun, out: SimOutputs) -> None:
    """Raise, in one line, if the measured effort fits the nominal twin's better with its sign
    reversed (module docstring)."""
    name = run.effort_name
    if name is None or out.effort is None or not np.all(np.isfinite(out.effort[0])):
        return
    as_recorded, reversed_ = sign_fits(run, out.effort[0])
    if as_recorded <= REVERSED_FIT_RATIO * reversed_:
        return
    n = len(run.t_s)
    unit = EFFORT_UNITS.get(name, "")
    raise MeasuredDataError(
        f"{run.source}: the measured {name} fits the nominal twin's better with its sign "
        f"reversed (RMS left {np.sqrt(reversed_ / n):.3g} {unit} against "
        f"{np.sqrt(as_recorded / n):.3g} {unit} as recorded, each with a free scale, weight "
        "and friction): its sign looks reversed; give its column a negative gain in the map"
    )
