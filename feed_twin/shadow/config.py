"""The `shadow:` section of an axis YAML: stream timing, message-fault policy, health limits.

    shadow:
      sample_period_s: 1.0e-3     # the machine's command/measurement cycle [s]
      stamp_tolerance: 0.25       # a stamp may sit this fraction of a period off its slot [1]
      reorder_window: 5           # slots a stream may run ahead before a gap is final [1]
      missing_fill: interpolate   # hold | interpolate: what fills a lost sample
      missing_flag_after: 20      # this many lost measured samples in a row -> STALE [1]
      window_s: 2.0               # rolling residual statistics window [s]
      baseline_s: 4.0             # baseline window from the start of the run [s]
      evaluate_period_s: 0.5      # health is judged this often (machine time) [s]
      fe_dev_rms_warn_m: 2.0e-6   # rolling RMS rise over the baseline that warns [m]
      fe_dev_rms_error_m: 2.0e-5  # ... that is an error [m]
      effort_dev_rms_warn: 2.0    # effort-deviation RMS rise that warns [effort unit]
      effort_dev_rms_error: 20.0  # ... that is an error [effort unit]
      standin:                    # the real-axis stand-in (optional; these are the defaults)
        jitter_s: 2.0e-4          # largest extra send delay of a message, real time only [s]
        current_lag_s: 2.0e-4     # the truth drive's current-loop lag, not in the twin [s]
        coupling_stiffness_factor: 0.97  # truth / model torsional coupling stiffness [1]
        effort_noise_std: null    # white noise on the reported effort [effort unit];
                                  # null: 0.3 N (force) or 0.01 A (current)
        seed: 0                   # of the effort noise and the send jitter
        hidden: {}                # hidden effects from the start: effect -> parameters, as
                                  # feed_twin.analysis.synthetic.HIDDEN takes them, e.g.
                                  # {coulomb_friction: {F_c_N: 150.0}}
        friction_steps: []        # during the run: [{at_s: 3.0, scale: 2.0}] sets the truth's
                                  # Coulomb friction to scale x its start value at machine time
                                  # at_s (seconds after the first command)

The effort unit is the measured effort's SI unit (N, N m or A), as in the discrepancy workflow.
The stand-in (feed_twin.shadow.standin, feed_twin.ros.standin_node) plays the real machine in
`feed-twin shadow` and `feed-twin run PROGRAM --shadow`; the twin never reads `standin`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_nonnegative, require_positive, require_range

SECTION = "shadow"


@dataclass(frozen=True, kw_only=True)
class FrictionStep:
    at_s: float  # [s] machine time after the first command
    scale: float  # [1] truth Coulomb friction / its value at the start

    def __post_init__(self) -> None:
        require_nonnegative("at_s", self.at_s)
        require_positive("scale", self.scale)


@dataclass(frozen=True, kw_only=True)
class StandInConfig:
    """What makes the stand-in's truth differ from the model (module docstring)."""

    jitter_s: float = 2.0e-4  # [s] largest extra send delay of a message (real-time runs)
    current_lag_s: float = 2.0e-4  # [s] first-order lag of the truth drive's current loop
    coupling_stiffness_factor: float = 0.97  # [1] truth / model coupling stiffness
    effort_noise_std: float | None = None  # [effort unit]; None: 0.3 N or 0.01 A
    seed: int = 0
    hidden: Any = field(default_factory=dict)  # effect -> {parameter: value}
    friction_steps: tuple[FrictionStep, ...] = ()

    def __post_init__(self) -> None:
        from feed_twin.analysis.synthetic import HIDDEN

        require_nonnegative("jitter_s", self.jitter_s)
        if not isinstance(self.hidden, Mapping):
            raise ValueError(
                f"hidden = {self.hidden!r}: must be a mapping effect -> {{parameter: value}}"
            )
        for effect, params in self.hidden.items():
            if effect not in HIDDEN:
                raise ValueError(
                    f"hidden.{effect}: unknown effect; one of {', '.join(sorted(HIDDEN))}"
                )
            if not isinstance(params, Mapping) or not all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in params.values()
            ):
                raise ValueError(
                    f"hidden.{effect} = {params!r}: must be a mapping parameter -> number"
                )
        frozen = {e: MappingProxyType(dict(p)) for e, p in self.hidden.items()}
        object.__setattr__(self, "hidden", MappingProxyType(frozen))
        times = [s.at_s for s in self.friction_steps]
        if times != sorted(times):
            raise ValueError(f"friction_steps: at_s = {times!r}: must be in increasing order")
        # the rest (lag, stiffness factor, noise) is checked by Unmodelled
        self.unmodelled()

    def unmodelled(self):
        """The synthetic generator's `Unmodelled` of this stand-in."""
        from feed_twin.analysis.synthetic import Unmodelled

        return Unmodelled(
            current_lag_s=self.current_lag_s,
            coupling_stiffness_factor=self.coupling_stiffness_factor,
            effort_noise_std=self.effort_noise_std,
            seed=self.seed,
        )


@dataclass(frozen=True, kw_only=True)
class ShadowConfig:
    sample_period_s: float  # [s] period of the machine's command and measured streams
    stamp_tolerance: float  # [1] largest |stamp - slot time| / period accepted as on the grid
    reorder_window: int  # [1] slots a stream may be ahead of a missing sample before it is final
    missing_fill: Literal["hold", "interpolate"]
    missing_flag_after: int  # [1] consecutive missing measured samples that make the twin STALE
    window_s: float  # [s] rolling statistics window
    baseline_s: float  # [s] baseline window at the start of the run
    evaluate_period_s: float  # [s] health evaluation period, machine time
    fe_dev_rms_warn_m: float  # [m] rise of the rolling following-error deviation RMS: WARN
    fe_dev_rms_error_m: float  # [m] ... ERROR
    effort_dev_rms_warn: float  # [effort unit] rise of the rolling effort deviation RMS: WARN
    effort_dev_rms_error: float  # [effort unit] ... ERROR
    standin: StandInConfig = field(default_factory=StandInConfig)

    def __post_init__(self) -> None:
        require_positive("sample_period_s", self.sample_period_s)
        require_range("stamp_tolerance", self.stamp_tolerance, 0.0, 0.5)
        for name in ("reorder_window", "missing_flag_after"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r}: must be a whole number >= 1")
        if self.missing_fill not in ("hold", "interpolate"):
            raise ValueError(
                f"missing_fill = {self.missing_fill!r}: must be 'hold' or 'interpolate'"
            )
        for name in ("window_s", "baseline_s", "evaluate_period_s"):
            require_positive(name, getattr(self, name))
            if getattr(self, name) < 10 * self.sample_period_s:
                raise ValueError(
                    f"{name} = {getattr(self, name)!r}: must span at least 10 samples "
                    f"(10 * sample_period_s = {10 * self.sample_period_s!r} s)"
                )
        for kind in ("fe_dev_rms", "effort_dev_rms"):
            unit = "_m" if kind == "fe_dev_rms" else ""
            warn, error = f"{kind}_warn{unit}", f"{kind}_error{unit}"
            require_positive(warn, getattr(self, warn))
            require_positive(error, getattr(self, error))
            if getattr(self, error) <= getattr(self, warn):
                raise ValueError(
                    f"{error} = {getattr(self, error)!r}: must be above "
                    f"{warn} = {getattr(self, warn)!r}"
                )

    @property
    def window_samples(self) -> int:
        return max(10, round(self.window_s / self.sample_period_s))

    @property
    def baseline_samples(self) -> int:
        return max(10, round(self.baseline_s / self.sample_period_s))

    @property
    def evaluate_samples(self) -> int:
        return max(1, round(self.evaluate_period_s / self.sample_period_s))


def load_shadow_config(data: str | Path | Mapping[str, Any], *, source: str | None = None):
    """The `shadow:` section of a YAML file (or of a parsed mapping) as a ShadowConfig."""
    if isinstance(data, Mapping):
        doc = dict(data)
        source = source or "<mapping>"
    else:
        doc = load_yaml(data)
        source = source or str(data)
    if SECTION not in doc:
        raise ConfigError(f"{source}: missing required section {SECTION}")
    return from_mapping(ShadowConfig, doc[SECTION], source=source, path=SECTION)
