"""Fitted values that no machine of the nominal model's kind would have, with their likely cause.

A fit finds the parameters that best explain the record within the model it is given; when the
model lacks something, a parameter that can mimic it takes it over, and its value says so:
- a moving mass several times the slide's (outside MASS_FACTOR either way): the effort's scale
  is not the model's (torque constant, gear, the current's unit), and the mass, which scales
  the force of every acceleration, absorbs it (said with the correlation when the two were
  fitted together);
- a stiffness ten times below or above its nominal (STIFFNESS_FACTOR): a soft spring stands in
  for lost motion (backlash) or a compliance elsewhere;
- any other re-fitted nominal parameter moved by more than FACTOR (not a found effect's own
  size: a backlash found 5x the model's is the finding);
- a constant force larger than the slide's whole weight m g: an offset of the measured current
  or the effort's sign; one that points against a modelled weight: the sign;
- a Stribeck speed above every speed of the record: the law is used where it means nothing; a
  friction that changed over the record (drift) or a viscous term is the likely cause. The
  rounds (analysis.rounds) do not keep such a fit at all (`outside_record`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from feed_twin.analysis.effects import Motion
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.report import FoundEffect

MASS_FACTOR = 3.0
STIFFNESS_FACTOR = 10.0
FACTOR = 5.0
G = 9.80665  # [m/s^2]


def _ratio_flag(
    slot: str, nominal: float, value: float, correlated: Iterable[str], *, owned: bool
) -> str | None:
    ratio = value / nominal
    short = slot.rsplit(".", 1)[-1]
    if short == "m":
        limit, cause = (
            MASS_FACTOR,
            (
                "the effort's scale (torque constant, gear or the current's unit) is not the "
                "model's, and the mass, which scales every acceleration's force, absorbs it"
            ),
        )
    elif short.startswith(("k", "EA", "c_")):
        limit, cause = (
            STIFFNESS_FACTOR,
            ("a soft spring stands in for lost motion (backlash) or a compliance elsewhere"),
        )
    elif owned:
        return None  # a found effect's own size: changing it is what the effect is
    else:
        limit, cause = FACTOR, "it stands in for an effect the model lacks"
    if 1.0 / limit <= abs(ratio) <= limit and ratio > 0.0:
        return None
    with_ = list(correlated)
    also = f" (its estimate is correlated with {', '.join(with_)})" if with_ else ""
    return (
        f"{slot} = {value:.4g} is {ratio:.3g} x its nominal {nominal:.4g}: implausible for this "
        f"machine; likely cause: {cause}{also}"
    )


def implausible(
    nominal: ModelDoc,
    final: ModelDoc,
    fitted: Iterable[str],
    effects: Iterable[FoundEffect],
    *,
    v_max_m_s: float,
    correlated: Mapping[str, list[str]],
    owned: Iterable[str] = (),
) -> list[str]:
    """One line per implausible fitted value (module docstring); `fitted` the slots the fit
    moved, `owned` those that are found effects' own sizes (only the mass and stiffness rules
    hold for them), `correlated` each slot's strongly correlated partners."""
    owned = set(owned)
    flags = []
    for slot in fitted:
        if not (nominal.has_slot(slot) and final.has_slot(slot)):
            continue
        before = nominal.get(slot)
        if before == 0.0 or slot.endswith("phase"):
            continue
        flag = _ratio_flag(
            slot, before, final.get(slot), correlated.get(slot, []), owned=slot in owned
        )
        if flag is not None:
            flags.append(flag)
    mass = nominal.mass_slot()
    weight = G * nominal.get(mass) if mass is not None else None
    for e in effects:
        f_0 = e.parameters.get("f_0_N")
        if f_0 is not None and weight is not None:
            flags += _force_flags(nominal, f_0, weight)
        v_s = e.parameters.get("v_s_m_s")
        if v_s is not None and v_s > v_max_m_s:
            flags.append(
                f"{e.name}: the Stribeck speed {v_s:.3g} m/s lies above every speed of the "
                f"record (at most {v_max_m_s:.3g} m/s): the law is fitted where it means "
                "nothing; likely cause: a friction that changed over the record (see drift) "
                "or a viscous friction"
            )
    return flags


def outside_record(name: str, parameters: Mapping[str, float], motion: Motion) -> str | None:
    """Why an effect fitted with these parameters is no finding on this record (its law is
    used outside the range the record holds), None if it is one. A Stribeck speed above every
    speed of the record makes the Stribeck law a Coulomb force less a term in v^2, which fits
    any lag a little better than the Coulomb force it stands for."""
    v_s = parameters.get("v_s_m_s")
    v_max = float(np.max(np.abs(motion.v_m_s)))
    if v_s is not None and v_s > v_max:
        return (
            f"{name} was fitted with a Stribeck speed of {v_s:.3g} m/s, above every speed of the "
            f"record (at most {v_max:.3g} m/s): not a Stribeck law"
        )
    return None


def _force_flags(nominal: ModelDoc, f_0: float, weight: float) -> list[str]:
    flags = []
    if abs(f_0) > weight:
        flags.append(
            f"constant_force: {f_0:.4g} N is more than the slide's whole weight "
            f"(m g = {weight:.4g} N): implausible; likely cause: an offset of the measured "
            "current or the effort's sign"
        )
    for name in nominal.of_type("Gravity"):
        modelled = nominal.get(f"{name}.weight")  # the weight pulls along -weight
        if modelled != 0.0 and f_0 * modelled > 0.0 and abs(f_0) > 0.5 * abs(modelled):
            flags.append(
                f"constant_force: {f_0:.4g} N pushes against the modelled weight "
                f"({-modelled:.4g} N along the axis): an upward weight; likely cause: the "
                "effort's sign"
            )
    return flags
