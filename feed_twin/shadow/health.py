"""Health of a shadowed axis: rolling residual statistics against a baseline, and what changed.

The residuals are the following-error deviation `fe_dev = e_meas - e_twin = x_twin - x_meas`
[m] and the effort deviation `effort_dev = effort_meas - effort_twin` [effort unit], as in the
discrepancy workflow. A model never matches a machine exactly, so health compares the machine
with ITSELF at the start of the run:

- baseline: the first `baseline_s` of residuals give the baseline RMS of both deviations and a
  baseline residual model: every effort-domain signature of the effect library
  (feed_twin.analysis.effects), fitted jointly to the baseline effort residual by least squares;
- every `evaluate_period_s`, the RMS over the last `window_s` is compared with the baseline RMS:
  a rise above `*_warn` is WARN, above `*_error` ERROR;
- on WARN or ERROR (at most once per `window_s`, and whenever the level rises, because ranking
  costs about 0.1 s) the window's effort residual minus the baseline model's prediction on the
  window's motion (what changed since the start) is ranked with the library's `rank`; the
  leading significant effect is named, and its least-squares weight converted to the physical
  parameter it belongs to (Coulomb and viscous friction, moving mass, constant force) and set
  against the model's value: "coulomb_friction +35 % since start". A window that cannot tell
  the first candidate from the effect an earlier window identified (adding its signature to
  that effect's is not significant) keeps the earlier name, and says so;
- STALE when the measured stream has lost `missing_flag_after` samples in a row.

A machine that reports no effort (`has_effort=False`, a controller such as LinuxCNC beside the
twin) is judged on the FE deviation alone. Its servo loop is rarely the twin's (other gains,
feed-forward, drive lag), and two linear servos that follow one command differ in following
error by, to first order, `c0 + c_v v + c_a a`: the baseline learns those three weights on its
window (the model gap), and the window RMS compared with the baseline is that of what the gap
model leaves, so a gap that was there from the start raises no alarm when the program's speed
changes. A gap larger than the warn threshold is said once, as a model gap (effect
`model_gap`, WARN), with the `feed-twin diagnose` command that fits the model to this machine,
and GAP_TOLERANCE of its RMS is added to the FE limits (the fit extrapolates to other motion);
the position-domain signatures of the library are ranked on what the gap model leaves (weights
in m, no parameter).

In a `Verdict`, `nominal_value` is the model's value of the parameter, `estimated_value` that
value plus the change since the start, and `relative_change` the change over |nominal_value|
(as HealthStatus defines it). The change is referred to the model's value, not to a baseline
estimate of the parameter itself: the library's signatures overlap (Coulomb, Stribeck and
asymmetric friction all follow the direction of motion), so a joint fit cannot split the
baseline residual between them, while the change since the start is well determined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from feed_twin.analysis.effects import BY_NAME, motion_from_position
from feed_twin.analysis.ranking import Candidate, rank, test_regressors
from feed_twin.analysis.significance import ALPHA
from feed_twin.shadow.config import ShadowConfig

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
MIN_SPEED_M_S = 1e-4  # [m/s] below this peak speed in a window nothing can be attributed
# Ranking works on the window decimated to at most this many samples: the signatures of
# friction, mass and force effects are smooth functions of the motion, and ranking a 4000-sample
# window costs about 0.1 s, which a live twin cannot spend every few seconds.
NAMING_SAMPLES = 500
MAX_BASELINE_EFFECTS = 4  # effects the baseline residual model may hold
# An effect whose fitted terms cancel each other more than this is not identified on the window
# (|v| and "moving" on a cruise at one speed): its weights would be reported as its size.
MAX_CANCELLATION = 10.0
# The model gap is learnt on the baseline window's motion only; on other motion (a reversal the
# baseline did not hold, another speed) it extrapolates to within a few per cent of the gap.
# That share of the gap's RMS is added to the FE limits, so a 66 um gap does not warn over a
# 2 um mismatch of its own fit (the README's LinuxCNC example gave 52 such warnings).
GAP_TOLERANCE = 0.1


@dataclass(frozen=True, kw_only=True)
class PhysicalEffect:
    """How one library effect's regressor weight maps to a model parameter."""

    effect: str  # library name, e.g. "coulomb_friction"
    regressor: str  # the signature column whose weight is the change, e.g. "sign_v"
    parameter: str  # dotted config path, e.g. "plant.friction.F_c"
    unit: str  # SI unit of the parameter
    nominal: float  # model value [unit]
    per_effort: float  # parameter units per (effort unit * regressor unit)


@dataclass(frozen=True, kw_only=True)
class Verdict:
    t_s: float  # machine time of the last sample judged [s]
    level: int  # OK, WARN, ERROR or STALE
    fe_dev_rms_m: float  # rolling RMS over the window [m]
    effort_dev_rms: float  # rolling RMS over the window [effort unit]
    baseline_fe_dev_rms_m: float
    baseline_effort_dev_rms: float
    effect: str = ""
    parameter: str = ""
    unit: str = ""
    nominal_value: float = math.nan
    estimated_value: float = math.nan
    relative_change: float = math.nan
    message: str = ""

    @property
    def level_name(self) -> str:
        return LEVEL_NAMES[self.level]


class _Ring:
    """The last `size` rows of a few float columns (bounded memory, O(rows) to add)."""

    def __init__(self, size: int, width: int) -> None:
        self.size = size
        self.buf = np.zeros((size, width))
        self.pos = 0
        self.count = 0

    def extend(self, rows: np.ndarray) -> None:
        rows = rows[-self.size :]
        n = len(rows)
        first = min(n, self.size - self.pos)
        self.buf[self.pos : self.pos + first] = rows[:first]
        self.buf[: n - first] = rows[first:]
        self.pos = (self.pos + n) % self.size
        self.count = min(self.count + n, self.size)

    @property
    def data(self) -> np.ndarray:
        """The rows in arrival order (a copy)."""
        if self.count < self.size:
            return self.buf[: self.count].copy()
        return np.concatenate([self.buf[self.pos :], self.buf[: self.pos]])


class HealthMonitor:
    """Judge the residual stream; `update` takes blocks of residual rows in slot order."""

    COLUMNS = ("t_s", "x_meas_m", "fe_dev_m", "effort_dev", "effort_twin")

    def __init__(
        self,
        config: ShadowConfig,
        *,
        physical: tuple[PhysicalEffect, ...],
        effort_unit: str,
        lead_m: float | None,
        pole_pairs: int | None,
        travel_m: float,
        has_effort: bool = True,
    ) -> None:
        self.config = config
        self.has_effort = has_effort  # False: the machine sends no effort, name by position
        self.physical = {p.effect: p for p in physical}
        self.effort_unit = effort_unit
        self.lead_m = lead_m
        self.pole_pairs = pole_pairs
        self.travel_m = travel_m
        self._window = _Ring(config.window_samples, len(self.COLUMNS))
        self._baseline_rows: list[np.ndarray] = []
        self._baseline_count = 0
        self.baseline: dict[str, float] | None = None
        self._baseline_model: list[tuple[str, str, dict[str, float]]] = []
        self._since_eval = 0
        self.verdicts: list[Verdict] = []  # every evaluation, most recent last
        self._naming: dict = {}
        self._baseline_note = ""
        self._invalid_run = 0  # consecutive rows without a real measured sample
        self._t_last = math.nan
        self._named_at: float | None = None
        # the effect the last window that identified one named (None after an OK verdict): a
        # window that cannot tell another effect from it does not rename it (_name_effect)
        self._identified: str | None = None
        self.last: Verdict | None = None
        self._gap: np.ndarray | None = None  # [m, s, s^2] FE deviation per (1, v, a) at baseline
        self.model_gap: Verdict | None = None  # said once when the baseline is set

    @property
    def gap_model(self) -> np.ndarray | None:
        """[m, s, s^2] the FE deviation's weights on (1, v, a) learnt at baseline (no effort)."""
        return None if self._gap is None else self._gap.copy()

    @property
    def baseline_ready(self) -> bool:
        return self.baseline is not None

    def update(self, rows: np.ndarray, *, valid: np.ndarray) -> list[Verdict]:
        """Add residual rows (columns COLUMNS; only the `valid` ones enter the statistics, all
        count for the evaluation period and the run of invalid ones makes the twin STALE);
        return the verdicts evaluated on the way."""
        out: list[Verdict] = []
        # rows before this index came before the baseline was complete: an evaluation there
        # says nothing, as it would not have with the rows handed over one at a time
        baseline_ready_at = 0
        if self.baseline is None:
            good = rows[valid]
            need = self.config.baseline_samples - self._baseline_count
            self._baseline_rows.append(good[:need])
            self._baseline_count += len(good[:need])
            if self._baseline_count >= self.config.baseline_samples:
                self._set_baseline(np.concatenate(self._baseline_rows))
                self._baseline_rows = []
                baseline_ready_at = int(np.flatnonzero(valid)[need - 1]) + 1
                if self.model_gap is not None:
                    out.append(self.model_gap)
            else:
                baseline_ready_at = len(rows) + 1
        start, n = 0, len(rows)
        while start < n:
            stop = start + self.config.evaluate_samples - self._since_eval
            good = valid[start:stop]
            self._window.extend(rows[start:stop][good])
            self._since_eval += len(good)
            real = np.flatnonzero(good)
            self._invalid_run = (
                len(good) - 1 - int(real[-1]) if len(real) else self._invalid_run + len(good)
            )
            self._t_last = float(rows[min(stop, n) - 1, 0])
            start = min(stop, n)
            if self._since_eval >= self.config.evaluate_samples:
                self._since_eval = 0
                stale = self._invalid_run >= self.config.missing_flag_after
                if start < baseline_ready_at and not stale:
                    continue
                verdict = self.evaluate(stale=stale)
                if verdict is not None:
                    out.append(verdict)
        return out

    def evaluate(self, *, stale: bool = False) -> Verdict | None:
        """Judge the current window against the baseline (None before the baseline is set,
        unless the measurement is stale: that is said at any time)."""
        empty = self._window.count == 0
        if (self.baseline is None or empty) and not stale:
            return None
        w = self._window.data
        b = self.baseline or {"fe_dev_rms_m": math.nan, "effort_dev_rms": math.nan}
        fe_rms = math.nan if empty else float(np.sqrt(np.mean(self._fe_change(w) ** 2)))
        eff_rms = math.nan if empty else float(np.sqrt(np.mean(w[:, 3] ** 2)))
        common: dict[str, Any] = dict(  # the fields every verdict of this cycle shares
            t_s=self._t_last if stale else float(w[-1, 0]),
            fe_dev_rms_m=fe_rms,
            effort_dev_rms=eff_rms,
            baseline_fe_dev_rms_m=b["fe_dev_rms_m"],
            baseline_effort_dev_rms=b["effort_dev_rms"],
        )
        c = self.config
        if stale:
            verdict = Verdict(
                level=STALE,
                message=f"no measured samples for {c.missing_flag_after} cycles or more",
                **common,
            )
        else:
            rise_fe = fe_rms - b["fe_dev_rms_m"]
            rise_eff = eff_rms - b["effort_dev_rms"]
            gap = GAP_TOLERANCE * self.model_gap.fe_dev_rms_m if self.model_gap else 0.0
            level = OK
            if rise_fe > c.fe_dev_rms_error_m + gap or rise_eff > c.effort_dev_rms_error:
                level = ERROR
            elif rise_fe > c.fe_dev_rms_warn_m + gap or rise_eff > c.effort_dev_rms_warn:
                level = WARN
            if level == OK:
                self._identified = None
                verdict = Verdict(level=OK, message="residuals at their baseline", **common)
            else:
                rises = (
                    f"FE deviation RMS {rise_fe * 1e6:+.3g} um, effort deviation RMS "
                    f"{rise_eff:+.3g} {self.effort_unit} since start"
                )
                t_now = float(w[-1, 0])
                due = self._named_at is None or t_now - self._named_at >= c.window_s - 1e-9
                if due or self.last is None or level > self.last.level:
                    self._naming = self._name_effect(w)
                    self._named_at = t_now
                naming = dict(self._naming)
                naming["message"] = f"{naming['message']}; {rises}"
                verdict = Verdict(level=level, **common, **naming)
        self.verdicts.append(verdict)
        if len(self.verdicts) > 10_000:
            del self.verdicts[:5_000]
        self.last = verdict
        return verdict

    def _motion(self, w: np.ndarray):
        effort = w[:, 4]
        # a constant twin effort has no shape: the effort-shaped signatures would be 0/0
        has_shape = bool(np.all(np.isfinite(effort))) and float(np.ptp(effort)) > 0.0
        return motion_from_position(
            w[:, 0],
            w[:, 1],
            effort_sim=effort if has_shape else None,
            lead_m=self.lead_m,
            pole_pairs=self.pole_pairs,
            travel_m=self.travel_m,
        )

    def _moving(self, w: np.ndarray) -> bool:
        x = w[:, 1]
        h = self.config.sample_period_s
        return len(x) > 20 and float(np.max(np.abs(np.diff(x)))) / h > MIN_SPEED_M_S

    def _gap_regressors(self, w: np.ndarray) -> np.ndarray:
        """Columns 1, v, a of the window (velocity and acceleration of the measured position)."""
        t, x = w[:, 0], w[:, 1]
        if len(t) < 3:
            return np.ones((len(t), 1))
        v = np.gradient(x, t)
        return np.column_stack([np.ones_like(t), v, np.gradient(v, t)])

    def _fe_change(self, w: np.ndarray) -> np.ndarray:
        """The window's FE deviation less the model gap learnt at baseline [m]."""
        if self._gap is None:
            return w[:, 2]
        return w[:, 2] - self._gap_regressors(w) @ self._gap

    def _set_baseline(self, rows: np.ndarray) -> None:
        raw_fe_rms = float(np.sqrt(np.mean(rows[:, 2] ** 2)))
        if not self.has_effort and self._moving(rows):
            Z = self._gap_regressors(rows)
            scale = np.linalg.norm(Z, axis=0)
            scale[scale == 0.0] = 1.0
            fitted, *_ = np.linalg.lstsq(Z / scale, rows[:, 2], rcond=1e-10)
            self._gap = fitted / scale
        self.baseline = {
            "fe_dev_rms_m": float(np.sqrt(np.mean(self._fe_change(rows) ** 2))),
            "effort_dev_rms": float(np.sqrt(np.mean(rows[:, 3] ** 2))),
        }
        if not self.has_effort and raw_fe_rms > self.config.fe_dev_rms_warn_m:
            self.model_gap = self._model_gap_verdict(rows, raw_fe_rms)
            self.verdicts.append(self.model_gap)
            self.last = self.model_gap
        if not self._moving(rows) or not self.has_effort:
            return
        rows = _decimated(rows)
        motion = self._motion(rows)
        try:
            self._baseline_model = self._fit_baseline(motion, rows[:, 3])
        except (np.linalg.LinAlgError, ValueError) as exc:
            self._baseline_note = f"baseline residual model not fitted: {exc}"

    def _model_gap_verdict(self, rows: np.ndarray, raw_fe_rms: float) -> Verdict:
        gap = self._gap if self._gap is not None and len(self._gap) == 3 else np.full(3, np.nan)
        c0, c_v, c_a = (float(c) for c in gap)
        left = self.baseline["fe_dev_rms_m"] if self.baseline else math.nan
        return Verdict(
            t_s=float(rows[-1, 0]),
            level=WARN,
            fe_dev_rms_m=raw_fe_rms,
            effort_dev_rms=math.nan,
            baseline_fe_dev_rms_m=left,
            baseline_effort_dev_rms=math.nan,
            effect="model_gap",
            message=(
                f"model gap from the start: FE deviation RMS {raw_fe_rms * 1e6:.3g} um over the "
                f"first {self.config.baseline_s:g} s (offset {c0 * 1e6:+.3g} um, "
                f"{c_v * 1e3:+.3g} um per mm/s, {c_a * 1e6:+.3g} um per m/s^2: the twin's servo "
                f"or plant is not this machine's; {left * 1e6:.3g} um RMS left), learnt as the "
                "baseline: alarms are for changes against it. To fit the model to this machine: "
                "feed-twin diagnose <this run's bag> --config <axis config> --out <dir>"
            ),
        )

    def _fit_baseline(self, motion, effort_dev: np.ndarray) -> list:
        """The effects the baseline window's effort deviation already holds, added one at a time
        while the next one is significant on what the others leave: fitting every ranked
        candidate at once lets near-collinear signatures (|v| and v on one-way moves, a
        standstill indicator on a moving window) take huge opposite weights that predict
        nonsense on the next window."""
        chosen: list[tuple[str, str]] = []
        coef: dict[tuple[str, str], dict[str, float]] = {}
        residual = effort_dev
        for _ in range(MAX_BASELINE_EFFECTS):
            ranked = rank(
                motion,
                effort_residual=residual,
                position_residual=None,
                exclude=tuple(name for name, _ in chosen),
            )
            found = _first_identified(ranked)
            if found is None:
                break
            chosen.append((found.name, found.variant))
            columns, owners = self._regressors(motion, chosen)
            Z = np.column_stack(list(columns.values()))
            scale = np.linalg.norm(Z, axis=0)
            scale[scale == 0.0] = 1.0
            fitted, *_ = np.linalg.lstsq(Z / scale, effort_dev, rcond=1e-10)
            fitted = fitted / scale
            residual = effort_dev - Z @ fitted
            coef = {}
            for (key, value), owner in zip(zip(columns, fitted, strict=True), owners, strict=True):
                coef.setdefault(owner, {})[key.split(":", 1)[1]] = float(value)
        return [(name, variant, c) for (name, variant), c in coef.items()]

    @staticmethod
    def _regressors(motion, chosen):
        columns: dict[str, np.ndarray] = {}
        owners: list[tuple[str, str]] = []
        for name, variant in chosen:
            effect = BY_NAME[name]
            for label, sig in effect.variants(motion):
                if label == variant:
                    for key, values in sig(motion).items():
                        columns[f"{name}:{key}"] = np.asarray(values, dtype=float)
                        owners.append((name, variant))
        return columns, owners

    def baseline_prediction(self, motion) -> np.ndarray:
        """The baseline residual model evaluated on another window's motion."""
        pred = np.zeros_like(motion.t_s)
        for name, variant, coefs in self._baseline_model:
            for label, sig in BY_NAME[name].variants(motion):
                if label == variant:
                    regs = sig(motion)
                    for key, c in coefs.items():
                        pred += c * regs[key]
        return pred

    def _name_effect(self, w: np.ndarray) -> dict:
        if not self._moving(w):
            return {"message": "the axis did not move enough to name an effect"}
        w = _decimated(w)
        motion = self._motion(w)
        unit = self.effort_unit
        try:
            if self.has_effort:
                change = w[:, 3] - self.baseline_prediction(motion)
                ranked = rank(motion, effort_residual=change, position_residual=None)
            else:
                # no measured effort: the position-domain signatures on what the model gap
                # learnt at baseline leaves of the FE deviation
                unit = "m"
                change = self._fe_change(w)
                ranked = rank(motion, effort_residual=None, position_residual=change)
            found = _first_identified(ranked)
            kept = self._kept(ranked, found, motion, change)
        except (np.linalg.LinAlgError, ValueError) as exc:
            # a twin must never stop over its diagnosis: report and go on
            return {"message": f"the effect ranking failed on this window ({exc})"}
        if found is None:
            return {"message": "no effect of the library explains the change"}
        alike = ""
        if kept is not None:
            alike = f"; this window alone cannot tell it from {found.name}"
            found = kept
        self._identified = found.name
        naming = self._sized(found, motion, unit)
        naming["message"] += alike
        return naming

    def _kept(self, ranked, found: Candidate | None, motion, residual) -> Candidate | None:
        """The effect an earlier window identified, where this window cannot tell `found` from
        it: on a one-way cruise at one speed a Coulomb, a viscous and a constant force, a
        Stribeck excess and a torque-constant error are all one offset, and the ranking's order
        among them is chance (a worn guide was once named viscous_friction +435 % there,
        Coulomb friction +100 % on the windows around). Kept while adding `found`'s signature
        to the earlier effect's explains nothing significant (a partial F-test, as ranking's)."""
        if found is None or self._identified in (None, found.name):
            return None
        earlier = next(
            (
                c
                for c in ranked
                if c.name == self._identified
                and c.significant
                and c.cancellation <= MAX_CANCELLATION
            ),
            None,
        )
        if earlier is None:
            return None
        held, _ = self._regressors(motion, [(earlier.name, earlier.variant)])
        added, _ = self._regressors(motion, [(found.name, found.variant)])
        nuisance = list(held.values())
        if found.residual_domain == "position":
            nuisance.append(np.ones_like(motion.t_s))  # the alignment's offset, as in rank
        _, _, p_value, _, _ = test_regressors(residual, added, np.column_stack(nuisance))
        return earlier if p_value >= ALPHA else None

    def _sized(self, found: Candidate, motion, unit: str) -> dict:
        """The verdict's naming of `found`: its parameter's change where one applies, else the
        effort it adds in the window."""
        phys = self.physical.get(found.name)
        if phys is None or phys.regressor not in found.coefficients:
            # its weights are sizes only where the window shows the whole signature (a Stribeck
            # bump needs slow motion): what the window determines is the effort it adds here
            columns, _ = self._regressors(motion, [(found.name, found.variant)])
            added = sum(found.coefficients[k.split(":", 1)[1]] * z for k, z in columns.items())
            peak = float(np.max(np.abs(added), initial=0.0))
            return {
                "effect": found.name,
                "message": f"{found.name} changed since start (adds up to {peak:.3g} {unit} "
                "in this window)",
            }
        start = phys.nominal
        now = start + phys.per_effort * found.coefficients[phys.regressor]
        rel = (now - start) / abs(start) if start != 0.0 else math.nan
        what = (
            f"{found.name} {100.0 * rel:+.0f} % since start"
            if math.isfinite(rel)
            else f"{found.name} {now - start:+.4g} {phys.unit} since start"
        )
        return {
            "effect": found.name,
            "parameter": phys.parameter,
            "unit": phys.unit,
            "nominal_value": start,
            "estimated_value": now,
            "relative_change": rel,
            "message": f"{what} ({start:.4g} -> {now:.4g} {phys.unit})",
        }


def _first_identified(ranked: list) -> Candidate | None:
    """The most explaining significant candidate whose weights the window determines."""
    return next((c for c in ranked if c.significant and c.cancellation <= MAX_CANCELLATION), None)


def _decimated(rows: np.ndarray) -> np.ndarray:
    return rows[:: max(1, len(rows) // NAMING_SAMPLES)]
