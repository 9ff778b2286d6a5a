"""How each effect of the library enters the model: which component, which free parameters.

An edit takes the current model document and the ranking's candidate (its least-squares weights
are the initial guess) and returns a new document with the effect's component added or its
parameters freed, plus the free parameters and the nominal ones that interact with it (those
are re-estimated together: adding Coulomb friction changes the best viscous coefficient and
mass). The original document is never modified.

Effects declared by their components (plant.component.OwnedEffect: constant_force in
external_force.py, backlash in backlash.py, stiction in stiction_friction.py) bring their own
edit, built with `make_edit`, `free_parameter` and `symmetric` from here. Effects whose
component the integrated model does not (yet) offer have no edit; the workflow still names them
with their evidence but cannot fit them, and says so.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from feed_twin.analysis.fit import FreeParameter
from feed_twin.analysis.ranking import Candidate
from feed_twin.analysis.twin import EFFORT_DELAY_SLOT, ModelDoc
from feed_twin.plant.registry import OWNED_EFFECTS


@dataclass(frozen=True, kw_only=True)
class Edit:
    doc: ModelDoc
    own: list[FreeParameter]  # the effect's own parameters (fitted first, alone)
    free: list[FreeParameter]  # own + the interacting ones (the final, joint fit)
    added: int  # degrees of freedom the effect adds to the model (for the partial F-test)
    # whole-number parameters are searched over these values instead of least squares
    grid: tuple[float, ...] = ()
    # reported parameter name -> function of the fitted slot values
    report: dict[str, Callable[[dict[str, float]], float]]


def symmetric(doc: ModelDoc) -> ModelDoc:
    """Tie forward/backward friction values that are equal, so they stay one parameter."""
    fr = doc.friction()
    if fr is None or doc.ties_of(fr) == "asymmetric":
        return doc
    for tied, pos, neg in (("F_c", "F_c_pos", "F_c_neg"), ("F_v", "F_v_pos", "F_v_neg")):
        if doc.get(f"{fr}.{pos}") == doc.get(f"{fr}.{neg}"):
            doc = doc.tie(f"{fr}.{tied}", (f"{fr}.{pos}", f"{fr}.{neg}"))
    return doc


def free_parameter(
    doc: ModelDoc,
    name: str,
    initial: float | None = None,
    *,
    lower: float = 0.0,
    floor: float = 1.0,
) -> FreeParameter:
    value = doc.get(name) if initial is None else initial
    return FreeParameter(name=name, initial=value, scale=max(abs(value), floor), lower=lower)


def interacting(doc: ModelDoc) -> list[FreeParameter]:
    """The rigid-body parameters every force-like effect trades off against, re-fitted with it:
    the moving mass, the friction terms the model already has, a constant force."""
    free = []
    m = doc.mass_slot()
    if m is not None:
        value = doc.get(m)
        free.append(FreeParameter(name=m, initial=value, scale=value, lower=0.2 * value))
    fr = doc.friction()
    if fr is not None:
        for tied, pos, neg in (("F_c", "F_c_pos", "F_c_neg"), ("F_v", "F_v_pos", "F_v_neg")):
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


def _friction_name(doc: ModelDoc) -> str:
    fr = doc.friction()
    if fr is None:
        raise LookupError("the model has no GuideFriction component")
    return fr


def make_edit(
    doc: ModelDoc,
    own: list[FreeParameter],
    report: dict[str, Callable[[dict[str, float]], float]],
    *,
    added: int | None = None,
    interacts: bool = True,
    grid: tuple[float, ...] = (),
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
    )


def coulomb(doc: ModelDoc, cand: Candidate) -> Edit:
    doc = symmetric(doc.with_friction())
    fr = _friction_name(doc)
    doc = doc.tie(f"{fr}.F_c", (f"{fr}.F_c_pos", f"{fr}.F_c_neg"))
    # the weight is the friction the twin lacks (measured minus twin), on top of what it has
    fc = max(doc.get(f"{fr}.F_c") + cand.coefficients.get("sign_v", 0.0), 1e-3)
    doc = doc.set(f"{fr}.F_c", fc)
    own = [free_parameter(doc, f"{fr}.F_c", fc)]
    return make_edit(doc, own, {"F_c_N": lambda v: v[f"{fr}.F_c"]})


def viscous(doc: ModelDoc, cand: Candidate) -> Edit:
    doc = symmetric(doc.with_friction())
    fr = _friction_name(doc)
    doc = doc.tie(f"{fr}.F_v", (f"{fr}.F_v_pos", f"{fr}.F_v_neg"))
    guess = max(doc.get(f"{fr}.F_v") + cand.coefficients.get("v", 0.0), 0.0)
    doc = doc.set(f"{fr}.F_v", guess)
    own = [free_parameter(doc, f"{fr}.F_v", guess)]
    return make_edit(doc, own, {"F_v_N_s_m": lambda v: v[f"{fr}.F_v"]})


def stribeck(doc: ModelDoc, cand: Candidate) -> Edit:
    doc = symmetric(doc.with_friction())
    fr = _friction_name(doc)
    vs = float(cand.variant.split("=")[1].split()[0]) if cand.variant else 0.005
    ds = max(doc.get(f"{fr}.dF_s") + cand.coefficients.get("stribeck", 0.0), 1e-3)
    doc = doc.set(f"{fr}.dF_s", ds).set(f"{fr}.v_s", vs)
    own = [
        free_parameter(doc, f"{fr}.dF_s"),
        free_parameter(doc, f"{fr}.v_s", lower=1e-4, floor=1e-3),
    ]
    report = {"dF_s_N": lambda v: v[f"{fr}.dF_s"], "v_s_m_s": lambda v: v[f"{fr}.v_s"]}
    return make_edit(doc, own, report)


def asymmetric(doc: ModelDoc, cand: Candidate) -> Edit:
    """Forward and backward friction apart. Coulomb is split only once Coulomb friction is in
    the model: a split Coulomb force alone would look like a constant force while moving."""
    doc = doc.with_friction()
    fr = _friction_name(doc)
    has_coulomb = doc.get(f"{fr}.F_c_pos") > 0.0 or doc.get(f"{fr}.F_c_neg") > 0.0
    doc = doc.untie().mark_asymmetric(fr)
    names = ("F_v_pos", "F_v_neg") + (("F_c_pos", "F_c_neg") if has_coulomb else ())
    own = [free_parameter(doc, f"{fr}.{n}") for n in names]
    report = {
        name: (lambda n: lambda v: v[f"{fr}.{n}"])(name)
        for name in ("F_c_pos", "F_c_neg", "F_v_pos", "F_v_neg")
    }
    # one more value per direction-split term than the symmetric model had
    return make_edit(doc, own, report, added=len(names) // 2)


def mass_error(doc: ModelDoc, cand: Candidate) -> Edit:
    m = doc.mass_slot()
    if m is None:
        raise LookupError("the model has no Mass component")
    doc = symmetric(doc)
    value = doc.get(m)
    guess = max(value + cand.coefficients.get("a", 0.0), 0.2 * value)
    doc = doc.set(m, guess)
    own = [FreeParameter(name=m, initial=guess, scale=value, lower=0.2 * value)]
    return make_edit(doc, own, {"m_kg": lambda v: v[m]})


def gain_error(doc: ModelDoc, cand: Candidate) -> Edit:
    g = doc.gain_slot()
    if g is None:
        raise LookupError("the model has no EffortSource component")
    doc = symmetric(doc)
    value = doc.get(g)
    # measured effort = K_nom/K_true * needed effort: weight c = K_nom/K_true - 1
    guess = value / (1.0 + cand.coefficients.get("effort", 0.0))
    doc = doc.set(g, guess)
    own = [FreeParameter(name=g, initial=guess, scale=abs(value))]
    # the gain scales every force of the model at once: fitted together with the mass and
    # friction it would be degenerate, so it is fitted alone
    return make_edit(doc, own, {"gain": lambda v: v[g]}, interacts=False)


def cogging(doc: ModelDoc, cand: Candidate) -> Edit:
    """A cogging harmonic of the order the signature found; amplitude and phase are fitted.

    The drive must supply -tau_cog = -A sin(k phi + psi), so the current residual is
    -(A/K_t) sin(k phi + psi): the weights (s, c) of (sin, cos) give A = K_t sqrt(s^2 + c^2)
    and psi = atan2(-c, -s).
    """
    k_t = doc.torque_constant()
    if k_t is None:
        raise LookupError("the model has no Pmsm")
    order = int(cand.variant.split()[1]) if cand.variant else 6
    s_w, c_w = cand.coefficients.get("sin", 0.0), cand.coefficients.get("cos", 0.0)
    amplitude = max(k_t * math.hypot(s_w, c_w), 1e-4)
    phase = math.atan2(-c_w, -s_w)
    doc, prefix = doc.with_cogging(order, amplitude, phase)
    own = [
        FreeParameter(name=f"{prefix}amplitude", initial=amplitude, scale=amplitude, lower=0.0),
        FreeParameter(name=f"{prefix}phase", initial=phase, scale=1.0),
    ]
    report = {
        "order": lambda v: float(order),
        "amplitude_Nm": lambda v: v[f"{prefix}amplitude"],
        "phase_rad": lambda v: v[f"{prefix}phase"],
    }
    return make_edit(doc, own, report, interacts=False)


def lead_error(doc: ModelDoc, cand: Candidate) -> Edit:
    """A once-per-revolution lead error in the axial compliance; amplitude and phase fitted.

    A linear scale reads the table at s + e(s), the twin at s: the position residual
    (twin minus measured) is -A sin(2 pi s / P + psi), so (sin, cos) weights (s, c) give
    A = hypot(s, c) and psi = atan2(-c, -s).
    """
    compliances = doc.of_type("AxialCompliance")
    screws = doc.of_type("BallScrew")
    if not compliances or not screws:
        raise LookupError("the model has no AxialCompliance and BallScrew to carry a lead error")
    name = compliances[0]
    lead = doc.get(f"{screws[0]}.lead")
    s_w, c_w = cand.coefficients.get("sin", 0.0), cand.coefficients.get("cos", 0.0)
    amplitude = max(math.hypot(s_w, c_w), 1e-9)
    phase = math.atan2(-c_w, -s_w)
    doc = doc.set_raw(name, "lead_error_period", lead)
    doc = doc.set(f"{name}.lead_error_amplitude", amplitude).set(f"{name}.lead_error_phase", phase)
    own = [
        FreeParameter(
            name=f"{name}.lead_error_amplitude", initial=amplitude, scale=amplitude, lower=0.0
        ),
        FreeParameter(name=f"{name}.lead_error_phase", initial=phase, scale=1.0),
    ]
    report = {
        "amplitude_m": lambda v: v[f"{name}.lead_error_amplitude"],
        "phase_rad": lambda v: v[f"{name}.lead_error_phase"],
        "period_m": lambda v: lead,
    }
    return make_edit(doc, own, report, interacts=False)


def thermal_drift(doc: ModelDoc, cand: Candidate) -> Edit:
    """Thermal growth of the screw (analysis.thermal); its heating rate [K/m] is fitted."""
    from feed_twin.analysis.thermal import initial_heating, with_thermal_growth

    heating = initial_heating(cand)
    doc, slot = with_thermal_growth(doc, heating)
    own = [FreeParameter(name=slot, initial=heating, scale=heating, lower=0.0)]
    report = {"heating_K_m": lambda v: v[slot]}
    return make_edit(doc, own, report, interacts=False)


def position_dependent_stiffness(doc: ModelDoc, cand: Candidate) -> Edit:
    """The axial rigidity EA of the screw and the support-bearing stiffness are fitted.

    The axial compliance is 1/k(x) = 1/k_bearing + c_screw(x)/EA + 1/k_nut (feed_twin.plant.
    axial_compliance): the position-dependent part identifies EA, the constant part the
    bearing (the nut's share stays nominal: a constant compliance cannot tell the two apart).
    Both are fitted in the log (scaled to order 1 by their nominal values): the deflection goes
    with their inverses and the truth may be a factor of several away, where a linear
    parametrisation left the trust region crawling. The screw's root diameter stays fixed;
    the document stores the fitted EA as Young's modulus.
    """
    compliances = doc.of_type("AxialCompliance")
    if not compliances:
        raise LookupError("the model has no AxialCompliance (screw) whose stiffness could vary")
    name = compliances[0]
    slots = (f"{name}.k_bearing", f"{name}.EA")
    own = [
        FreeParameter(name=slot, initial=doc.get(slot), scale=doc.get(slot), lower=0.0, log=True)
        for slot in slots
    ]
    report = {"k_bearing_N_m": lambda v: v[slots[0]], "EA_N": lambda v: v[slots[1]]}
    return make_edit(doc, own, report, interacts=False)


def current_offset(doc: ModelDoc, cand: Candidate) -> Edit:
    """The three per-phase offsets of the CurrentSensor are fitted.

    The offsets read as alpha/beta errors (2/3)(o_a - (o_b + o_c)/2), (o_b - o_c)/sqrt(3) (a
    part common to the three phases cancels there); the current loop makes the true i_q differ
    from the measured by -q = alpha sin(theta_e) - beta cos(theta_e), and the velocity loop
    adds that back to its i_q command, so the effort residual is about -alpha sin + beta cos:
    the (sin, cos) weights (s, c) give the initial guess alpha = -s, beta = c with no common
    part. The common part is fitted too: the drive's dead-time compensation switches on the
    sign of each measured phase current, so a phase offset also shifts where that happens.
    """
    sensors = doc.of_type("CurrentSensor")
    if not sensors:
        raise LookupError("the model has no CurrentSensor whose phase offsets could be fitted")
    name = sensors[0]
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
    report = {f"{slot.split('.')[1]}_A": (lambda s: lambda v: v[s])(slot) for slot in slots}
    return make_edit(doc, own, report, interacts=False)


def dead_time(doc: ModelDoc, cand: Candidate) -> Edit:
    """The Inverter's dead time t_dead is fitted (the controller's compensation stays as it is).

    Averaged inverter: the fitted engine slot is dead_fraction = t_dead f_pwm (stored as t_dead).
    Ranked on the q-voltage residual, the weight c of the signature is the extra voltage the
    controller must command, u_dc Delta t_dead f_pwm (analysis.effects), so the guess is
    dead_fraction + c / u_dc; ranked on the effort (no voltage recorded) the weight is in amperes
    and says nothing about the size, so the fit starts at the nominal value. The device drop u_f
    stays nominal: it has the same sgn(i) shape and cannot be told apart from the dead time.
    """
    inverters = doc.of_type("Inverter")
    if not inverters:
        raise LookupError("the model has no Inverter whose dead time could be fitted")
    name = inverters[0]
    params = doc.component(name)["params"]
    f_pwm = float(params["f_pwm"])
    switching = params.get("model") == "switching"
    slot = f"{name}.t_dead" if switching else f"{name}.dead_fraction"
    per_fraction = 1.0 / f_pwm if switching else 1.0  # slot units per unit of dead fraction
    fraction = doc.get(f"{name}.t_dead") * f_pwm
    u_dc = doc.bus_voltage()
    if cand.residual_domain == "voltage" and u_dc:
        fraction = fraction + cand.coefficients.get("sgn_i_q", 0.0) / u_dc
    # the Inverter accepts t_dead up to 10 % of the PWM period
    fraction = min(max(fraction, 1e-4), 0.09)
    doc = doc.set(slot, fraction * per_fraction)
    own = [
        FreeParameter(
            name=slot,
            initial=fraction * per_fraction,
            scale=fraction * per_fraction,
            lower=0.0,
            upper=0.099 * per_fraction,
        )
    ]
    to_seconds = 1.0 if switching else 1.0 / f_pwm
    return make_edit(doc, own, {"t_dead_s": lambda v: v[slot] * to_seconds}, interacts=False)


MAX_DELAY_TICKS = 8  # sample delays searched for measurement_delay [base periods]
# delays of the recorded effort behind the position searched for channel_delay: +/- this many
# base periods in half steps (a trace recorder's channels drift by milliseconds)
CHANNEL_DELAY_PERIODS = 20


def channel_delay(doc: ModelDoc, cand: Candidate) -> Edit:
    """The record's effort is stamped later than its position (or earlier): not a change of
    the machine, a shift of the twin's effort before it is compared (analysis.twin.delayed),
    searched over a grid and kept in the model's `analysis` section."""
    period = float(doc.data["controller"]["base_period_s"])
    grid = tuple(
        0.5 * period * k for k in range(-2 * CHANNEL_DELAY_PERIODS, 2 * CHANNEL_DELAY_PERIODS + 1)
    )
    doc = doc.set(EFFORT_DELAY_SLOT, doc.get(EFFORT_DELAY_SLOT))
    own = [FreeParameter(name=EFFORT_DELAY_SLOT, initial=0.0, scale=period)]
    report = {"delay_s": lambda v: v[EFFORT_DELAY_SLOT]}
    return make_edit(doc, own, report, interacts=False, grid=grid)


def measurement_delay(doc: ModelDoc, cand: Candidate) -> Edit:
    sensors = doc.of_type("Encoder") + doc.of_type("LinearScale")
    if not sensors:
        raise LookupError("the model has no Encoder or LinearScale")
    slots = tuple(f"{s}.delay_ticks" for s in sensors)
    name = "sensors.delay_ticks"
    doc = doc.tie(name, slots)
    period = float(doc.data["controller"]["base_period_s"])
    own = [FreeParameter(name=name, initial=doc.get(name), scale=1.0, lower=0.0)]
    report = {"delay_ticks": lambda v: v[name], "delay_s": lambda v: v[name] * period}
    # a delay in whole sensor samples: searched, not differentiated
    return make_edit(doc, own, report, interacts=False, grid=tuple(range(MAX_DELAY_TICKS + 1)))


EDITS: dict[str, Callable[[ModelDoc, Candidate], Edit]] = {
    **{effect.name: effect.edit for effect in OWNED_EFFECTS},
    "cogging_torque": cogging,
    "lead_error": lead_error,
    "measurement_delay": measurement_delay,
    "channel_delay": channel_delay,
    "coulomb_friction": coulomb,
    "viscous_friction": viscous,
    "stribeck_friction": stribeck,
    "asymmetric_friction": asymmetric,
    "mass_error": mass_error,
    "torque_constant_error": gain_error,
    "thermal_drift": thermal_drift,
    "position_dependent_stiffness": position_dependent_stiffness,
    "current_offset": current_offset,
    "dead_time": dead_time,
}
