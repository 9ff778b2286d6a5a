"""What a component needs to declare an effect the discrepancy workflow may add to it.

An effect is owned by the plant component that carries it: the component lists it in its
`EFFECTS` (feed_twin.plant.component) as an `Effect` with
- its signature: regressors, functions of the measured `Motion`, that the residual it causes
  would follow (ranked by feed_twin.analysis.ranking);
- its edit: the component's own parameters it frees in a model document (the inverse of its
  slots), with initial values from the ranking's least-squares weights, as an `Edit`;
- its truth: how a synthetic record sets it (feed_twin.analysis.synthetic).
feed_twin.plant.registry collects them; the analysis layer works on these declarations only, so
a new law is its component file plus one registry line. This module sits below the components
and imports nothing of the analysis: the model document is seen through the `Document`
protocol (feed_twin.analysis.model_doc.ModelDoc implements it), the ranking's candidate through
`Weights`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import numpy as np

from feed_twin.core.arrays import FloatArray

SMOOTH_VELOCITY_S = 0.005  # [s] smoothing window for velocity and acceleration estimates
# a table is moving, for the direction of its last move, above this many Motion.speed_eps
MOVING_SPEEDS = 5.0

Domain = Literal["effort", "position", "voltage"]


@dataclass(frozen=True, kw_only=True)
class Motion:
    """Measured motion and machine data the signatures are functions of (SI, one time base)."""

    t_s: FloatArray
    x_m: FloatArray  # measured table position
    v_m_s: FloatArray  # velocity estimate
    a_m_s2: FloatArray  # acceleration estimate
    effort_sim: FloatArray | None  # the twin's effort on this run (for gain errors)
    lead_m: float | None  # [m/rev] screw lead (motor angle = 2 pi x / lead for a direct drive)
    pole_pairs: int | None
    travel_m: float  # [m] stroke of the axis (for stiffness that depends on position)
    current_q_A: FloatArray | None = None  # measured q-current (or its command) [A]
    v_cmd_m_s: FloatArray | None = None  # commanded velocity [m/s] (None: the record has none)
    # the drive's current loop's answer: the q-current [A] a voltage error [V] on its windings
    # leaves (samples of one and of the other), for a twin that knows its current loop but has
    # no Inverter (analysis.drive_stage); None elsewhere
    current_answer: Callable[[FloatArray], FloatArray] | None = None
    # the twin's effort as the trace's other mode records it: each sample the mean over its
    # period where the twin takes it as it is, or the other way round (None: the record's
    # period is the twin's tick, or no effort)
    effort_other_mode: FloatArray | None = None
    # the recorded effort, in effort_sim's unit (None: the record has none)
    effort_meas: FloatArray | None = None

    @property
    def speed_eps(self) -> float:
        """Speed [m/s] that the sign regressors use to regularise sign(v) near standstill."""
        return 0.002 * float(np.max(np.abs(self.v_m_s)))


def motion_from_position(
    t_s: FloatArray,
    x_m: FloatArray,
    *,
    effort_sim: FloatArray | None,
    lead_m: float | None,
    pole_pairs: int | None,
    travel_m: float,
    current_q_A: FloatArray | None = None,
    v_cmd_m_s: FloatArray | None = None,
    current_answer: Callable[[FloatArray], FloatArray] | None = None,
    effort_other_mode: FloatArray | None = None,
) -> Motion:
    """Velocity and acceleration from a measured position by Savitzky-Golay differentiation.

    A quadratic fitted over SMOOTH_VELOCITY_S suppresses encoder quantisation, which plain
    differences would amplify by 1/h (and 1/h^2 for the acceleration).
    """
    t = np.asarray(t_s, dtype=float)
    h = float((t[-1] - t[0]) / (len(t) - 1))
    window = max(5, int(round(SMOOTH_VELOCITY_S / h)) | 1)
    x = np.asarray(x_m, dtype=float)
    v = _savgol(x, window, 1, h)
    a = _savgol(x, 2 * window + 1, 2, h)
    return Motion(
        t_s=t,
        x_m=x,
        v_m_s=v,
        a_m_s2=a,
        effort_sim=effort_sim,
        lead_m=lead_m,
        pole_pairs=pole_pairs,
        travel_m=travel_m,
        current_q_A=None if current_q_A is None else np.asarray(current_q_A, dtype=float),
        v_cmd_m_s=None if v_cmd_m_s is None else np.asarray(v_cmd_m_s, dtype=float),
        current_answer=current_answer,
        effort_other_mode=effort_other_mode,
    )


def direction(m: Motion) -> FloatArray:
    """sign(v), regularised over Motion.speed_eps."""
    return np.tanh(m.v_m_s / m.speed_eps)


def moving(m: Motion) -> FloatArray:
    return np.abs(direction(m))


def rate(y: FloatArray, t: FloatArray) -> FloatArray:
    """Time derivative by a 5-sample quadratic Savitzky-Golay filter (smooths the sample noise)."""
    h = float((t[-1] - t[0]) / (len(t) - 1))
    return _savgol(np.asarray(y, dtype=float), 5, 1, h)


def _savgol(y: FloatArray, window: int, deriv: int, h: float) -> FloatArray:
    """Quadratic Savitzky-Golay derivative of order `deriv` of samples `h` [s] apart."""
    # imported here: every process that builds an engine imports this module (plant.component)
    # and scipy.signal takes most of a second to import; only the analysis differentiates
    # scipy has no stubs: typed by the np.asarray below
    from scipy.signal import savgol_filter  # pyright: ignore[reportMissingTypeStubs, reportUnknownVariableType]

    return np.asarray(savgol_filter(y, window, 2, deriv=deriv, delta=h), dtype=float)


def effort_rate(m: Motion) -> dict[str, FloatArray]:
    """The signature of a delay of the effort: the rate of the twin's effort (y(t - d) is
    y(t) - d dy/dt to first order)."""
    assert m.effort_sim is not None
    return {"effort_rate": rate(m.effort_sim, m.t_s)}


def motor_angle(m: Motion) -> FloatArray:
    """Motor angle [rad] of a direct-drive screw: 2 pi x / lead."""
    assert m.lead_m is not None
    return 2.0 * math.pi * m.x_m / m.lead_m


def last_direction(m: Motion) -> FloatArray:
    """Direction of the last motion, held through stops: +1, -1, or 0 before the first move.

    Lost motion at a reversal leaves the table behind the nut by the half gap on the trailing
    side, and it stays there while the axis stands still (friction holds the table), so the
    position error follows the direction of the LAST move, not sign(v), which is 0 at rest.
    """
    is_moving = np.abs(m.v_m_s) > MOVING_SPEEDS * m.speed_eps
    heading = np.where(is_moving, np.sign(m.v_m_s), 0.0)
    last = np.maximum.accumulate(np.where(is_moving, np.arange(len(heading)), 0))
    held = heading[last]
    held[: int(np.argmax(is_moving))] = 0.0  # no move yet: the contact state is unknown
    return held


Signature = Callable[[Motion], dict[str, FloatArray]]


class Weights(Protocol):
    """The ranking's finding an edit starts from (feed_twin.analysis.ranking.Candidate)."""

    @property
    def variant(self) -> str: ...  # the chosen nonlinear parameter, "" if none

    @property
    def coefficients(self) -> dict[str, float]: ...  # regressor -> least-squares weight

    @property
    def residual_domain(self) -> str: ...  # the residual ranked

    @property
    def force_per_unit(self) -> float: ...  # [N at the table per unit of that residual]

    def force(self, regressor: str) -> float:
        """The weight of `regressor` as a force at the table [N per unit of the regressor]."""
        ...


class Document(Protocol):
    """A model document as an edit sees it (feed_twin.analysis.model_doc.ModelDoc)."""

    @property
    def data(self) -> dict[str, Any]: ...

    @property
    def ties(self) -> tuple[tuple[str, tuple[str, ...]], ...]: ...

    def component(self, name: str) -> dict[str, Any]: ...
    def of_type(self, kind: str) -> list[str]: ...
    def mass_slot(self) -> str | None: ...
    def friction(self) -> str | None: ...
    def gain_slot(self) -> str | None: ...
    def tie_names(self) -> tuple[str, ...]: ...
    def ties_of(self, friction: str) -> str: ...
    def get(self, slot: str) -> float: ...
    def base_period(self) -> float: ...
    def set(self, slot: str, value: float) -> Document: ...
    def set_raw(self, component: str, field_name: str, value: Any) -> Document: ...
    def tie(self, name: str, members: tuple[str, ...]) -> Document: ...
    def untie(self) -> Document: ...
    def mark_asymmetric(self, friction: str) -> Document: ...
    def with_table_component(
        self, base: str, kind: str, params: dict[str, Any]
    ) -> tuple[Document, str]: ...
    def with_component(
        self, base: str, kind: str, params: dict[str, Any], connect: list[list[str]]
    ) -> tuple[Document, str]: ...


@dataclass(frozen=True, kw_only=True)
class FreeParameter:
    name: str  # engine parameter slot, e.g. "friction.F_c_pos"
    initial: float
    scale: float  # typical magnitude, sets the finite-difference step and the solver scaling
    lower: float = -np.inf
    upper: float = np.inf
    # fitted as z = ln(value / scale): for a positive quantity known only to a factor (a
    # stiffness), whose effect goes with 1/value, so equal steps in z change the output alike
    log: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale > 0.0):
            raise ValueError(f"{self.name}: scale = {self.scale!r}: must be > 0")
        if self.log and not (self.initial > 0.0 and self.lower >= 0.0):
            raise ValueError(
                f"{self.name}: initial = {self.initial!r}, lower = {self.lower!r}: a log "
                f"parameter must start > 0 with lower >= 0"
            )
        if not self.lower < self.upper:
            raise ValueError(
                f"{self.name}: bounds [{self.lower!r}, {self.upper!r}]: lower must be < upper"
            )
        if not np.isfinite(self.initial):
            raise ValueError(f"{self.name}: initial = {self.initial!r}: must be finite")


Report = dict[str, Callable[[dict[str, float]], float]]  # reported name -> f(fitted slots)


@dataclass(frozen=True, kw_only=True)
class Edit:
    """An effect entered into a model document: the new document and what is fitted."""

    doc: Document
    own: list[FreeParameter]  # the effect's own parameters (fitted first, alone)
    free: list[FreeParameter]  # own + the interacting ones (the final, joint fit)
    added: int  # degrees of freedom the effect adds to the model (for the partial F-test)
    # parameters searched over these values instead of least squares (a delay in ticks)
    grid: tuple[float, ...] = ()
    # the searched parameter takes values between the grid's too (a sensor delay interpolates
    # between samples): the best grid value is refined between its neighbours (trials)
    refine: bool = False
    report: Report  # reported parameter name -> function of the fitted slot values
    # the edit writes a new stage that changes the model even at the effect's neutral values
    # (a drive's electrical stage for its dead time): the effect is tested against the edited
    # model at those values, not against the model before (analysis.rounds)
    restructures: bool = False


def free_parameter(
    doc: Document,
    name: str,
    initial: float | None = None,
    *,
    lower: float = 0.0,
    floor: float = 1.0,
) -> FreeParameter:
    value = doc.get(name) if initial is None else initial
    return FreeParameter(name=name, initial=value, scale=max(abs(value), floor), lower=lower)


def slot_reader(slot: str) -> Callable[[dict[str, float]], float]:
    """The report entry that reads one fitted slot."""
    return lambda v: v[slot]


# the forward/backward pairs of a GuideFriction and the tie that makes each one value
FRICTION_PAIRS = (("F_c", "F_c_pos", "F_c_neg"), ("F_v", "F_v_pos", "F_v_neg"))


def symmetric(doc: Document) -> Document:
    """Tie forward/backward friction values that are equal, so they stay one parameter."""
    fr = doc.friction()
    if fr is None or doc.ties_of(fr) == "asymmetric":
        return doc
    for tied, pos, neg in FRICTION_PAIRS:
        if doc.get(f"{fr}.{pos}") == doc.get(f"{fr}.{neg}"):
            doc = doc.tie(f"{fr}.{tied}", (f"{fr}.{pos}", f"{fr}.{neg}"))
    return doc


def interacting(doc: Document) -> list[FreeParameter]:
    """The rigid-body parameters every force-like effect trades off against, re-fitted with it:
    the moving mass, the friction terms the model already has, a constant force."""
    free: list[FreeParameter] = []
    m = doc.mass_slot()
    if m is not None:
        value = doc.get(m)
        free.append(FreeParameter(name=m, initial=value, scale=value, lower=0.2 * value))
    fr = doc.friction()
    if fr is not None:
        for tied, pos, neg in FRICTION_PAIRS:
            if f"{fr}.{tied}" in doc.tie_names():
                if doc.get(f"{fr}.{tied}") > 0.0:
                    free.append(free_parameter(doc, f"{fr}.{tied}"))
            else:
                for name in (pos, neg):
                    if doc.get(f"{fr}.{name}") > 0.0 or doc.ties_of(fr) == "asymmetric":
                        free.append(free_parameter(doc, f"{fr}.{name}"))
        if doc.get(f"{fr}.dF_s") > 0.0:
            free.append(free_parameter(doc, f"{fr}.dF_s"))
            free.append(free_parameter(doc, f"{fr}.v_s", lower=1e-4, floor=1e-3))
    for name in doc.of_type("ConstantForce"):
        free.append(free_parameter(doc, f"{name}.f_0", lower=-math.inf))
    return free


def make_edit(
    doc: Document,
    own: list[FreeParameter],
    report: Report,
    *,
    added: int | None = None,
    interacts: bool = True,
    grid: tuple[float, ...] = (),
    refine: bool = False,
) -> Edit:
    names = {p.name for p in own}
    others = [p for p in interacting(doc) if p.name not in names] if interacts else []
    return Edit(
        doc=doc,
        own=own,
        free=own + others,
        added=len(own) if added is None else added,
        report=report,
        grid=grid,
        refine=refine,
    )


def first_of(doc: Document, kind: str, why: str) -> str:
    """The name of the document's first component of type `kind`, or a LookupError saying
    "the model has no <kind> <why>" ("to carry cogging")."""
    found = doc.of_type(kind)
    if not found:
        raise LookupError(f"the model has no {kind} {why}")
    return found[0]


EditFn = Callable[[Document, Weights], Edit]
TruthFn = Callable[[Document, Mapping[str, float]], Document]


@dataclass(frozen=True, kw_only=True)
class Effect:
    """One effect of the library, as the component that carries it declares it."""

    name: str  # the effect's identifier in reports
    domain: Domain  # the residual its signature explains
    words: str  # what a machine-tool engineer calls it
    parameters: str  # the owner's slots it sets, for the report ("F_hold")
    edit: EditFn = field(repr=False)
    truth: TruthFn = field(repr=False)
    needs: tuple[str, ...] = ()  # Motion fields that must be known: lead_m, pole_pairs, ...
    signature: Signature | None = field(default=None, repr=False)
    # variants over a nonlinear parameter (Stribeck speed, cogging order); the best one is used;
    # none where the record holds none of the effect's evidence (it is not ranked there)
    choices: Callable[[Motion], list[tuple[str, Signature]]] | None = field(
        default=None, repr=False
    )
    # the domain ranked when the record lacks this effect's own residual (dead time without
    # voltages: the effort, where the current loop leaves only a trace of it)
    fallback: Domain | None = None
    owner: str = ""  # the component type that carries it (set by the registry)

    def __post_init__(self) -> None:
        if (self.signature is None) == (self.choices is None):
            raise ValueError(f"effect {self.name}: give exactly one of signature and choices")

    @property
    def component(self) -> str:
        """Where the effect lives in the model, for the report ("GuideFriction.F_c")."""
        return f"{self.owner}.{self.parameters}" if self.owner else self.parameters

    def variants(self, motion: Motion) -> list[tuple[str, Signature]]:
        if self.choices is not None:
            return self.choices(motion)
        assert self.signature is not None
        return [("", self.signature)]
