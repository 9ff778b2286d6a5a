"""The drive's electrical stage, inserted into a twin that models its drive as a torque source.

A twin whose drive is an ideal torque source (an EffortSource: the velocity loop's current
setpoint times K_t acts at once) has nothing for the inverter's dead time to act on: the dead
time eats u_dc t_dead f_pwm of every pole voltage against the phase current, the drive's PI
current loop makes the missing volts up within a few milliseconds after each reversal of the
current, and the actual current dips meanwhile. When the model's `analysis.drive_stage` gives
the drive's data sheet (`DriveStage`), `expand` writes the same axis with that stage, made of
the plant's own components and the controller's own current loop (no second copy of their
equations):
- the EffortSource becomes a Pmsm on its flange (windings R_s, L; flux psi_pm = K_t / (1.5 p)
  from the source's gain and `analysis.pole_pairs`; a negligible rotor of its own, the rotor's
  inertia stays where the model has it), fed by an averaged Inverter (dead time 0: the
  effect's edit fits it) from a stiff DcBus at u_dc, its phase currents measured by an exact
  CurrentSensor;
- the controller gets the drive's current loop (d/q PI at the data sheet's gains, neither
  decoupling nor back-EMF feed-forward unless it says so) at its period, which becomes the base
  period, and the loop's voltage applies one sample late (computation delay);
- the twin's effort stays the record's (a torque): the motor's actual q-current times the
  gain the record was converted with (analysis.twin: `expanded`).
The averaged inverter's law (plant.inverter): each pole loses u_dc t_dead f_pwm sgn(i_x), for
sine-triangle and min-max (SVPWM) modulation alike, since the lost high time per period is the
same for any duty; the three square waves are, in the rotor frame at i_d = 0, a q-voltage of
mean -(4/pi) u_dc t_dead f_pwm sgn(i_q) with a ripple at six times the electrical frequency.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from feed_twin.analysis.model_doc import ANALYSIS_SECTION, POLE_PAIRS_KEY, ModelDoc, model_of
from feed_twin.core.arrays import FloatArray
from feed_twin.core.config import from_mapping
from feed_twin.core.validate import require_positive
from feed_twin.plant.effect_api import Edit, EditFn, Weights, make_edit
from feed_twin.plant.effort_source import EffortSource

DRIVE_STAGE_KEY = "drive_stage"
# the Pmsm's own rotor [kg m^2]: 1e-4 of a small feed axis's inertia (plant.plausible
# allows no less than 1e-8)
ROTOR_J = 1.0e-7
# the largest dead time the fit may reach, as a share of the PWM period (2.5 us at 8 kHz;
# plant.inverter's limit is 10 %): the RK4 sub-steps are chosen for it (`_substeps`), 2 at the
# truth machine's data sheet, and each doubling of this share doubles them
MAX_DEAD_FRACTION = 0.02
# where the fit of the dead time starts, as a share of MAX_DEAD_FRACTION: a record without
# voltages says nothing of its size before the fit (plant.inverter)
START_SHARE = 0.5
# the current loop's answers kept per record (current_answer): one per i_reg of the dead time's
# signature (plant.inverter's DEAD_TIME_CURRENT_SCALES_A)
MAX_ANSWERS = 16
RK4_REAL_LIMIT = 2.5  # h |lambda| below this on a real eigenvalue (explicit RK4: 2.78)


@dataclass(frozen=True, kw_only=True)
class DriveStage:
    """The drive's electrical data sheet (`analysis.drive_stage`)."""

    R_s_ohm: float  # winding resistance per phase [ohm]
    L_H: float  # d and q inductance [H]
    u_dc_V: float  # DC bus [V]
    f_pwm_Hz: float  # switching frequency [Hz]
    current_period_s: float  # the current loop's sample period [s]
    Kp_V_A: float  # current PI gain [V/A]
    Ti_s: float  # current PI integral time [s]
    # [A] the phase current over which the dead time's voltage error changes sign (about the
    # PWM current ripple)
    i_reg_A: float
    decoupling: bool = False
    back_emf_ff: bool = False

    def __post_init__(self) -> None:
        for name in (
            "R_s_ohm", "L_H", "u_dc_V", "f_pwm_Hz", "current_period_s", "Kp_V_A", "Ti_s",
            "i_reg_A",
        ):  # fmt: skip
            require_positive(name, getattr(self, name))


def drive_stage(doc: ModelDoc) -> DriveStage | None:
    """The model's `analysis.drive_stage`, None where it gives none."""
    given = (doc.data.get(ANALYSIS_SECTION) or {}).get(DRIVE_STAGE_KEY)
    if given is None:
        return None
    return from_mapping(
        DriveStage, given, source=doc.source, path=f"{ANALYSIS_SECTION}.{DRIVE_STAGE_KEY}"
    )


def expandable(doc: ModelDoc) -> bool:
    """The model drives its motor through an ideal torque source and gives the drive's data
    sheet: `expand` can write its electrical stage."""
    return (
        not doc.of_type("Inverter")
        and len(doc.of_type(EffortSource.TYPE)) == 1
        and drive_stage(doc) is not None
    )


def expanded(doc: ModelDoc) -> bool:
    """The model is an `expand`ed one: its effort is its motor's actual current times the
    record's gain."""
    return bool(doc.of_type("Pmsm")) and drive_stage(doc) is not None


def expand(doc: ModelDoc) -> ModelDoc:
    """The model with the drive's electrical stage (module docstring) in place of its torque
    source; a LookupError names what is missing."""
    stage = drive_stage(doc)
    sources = doc.of_type(EffortSource.TYPE)
    if stage is None or len(sources) != 1 or doc.of_type("Inverter"):
        raise LookupError(
            f"{doc.source}: the model has no single EffortSource with the drive's data sheet "
            f"({ANALYSIS_SECTION}.{DRIVE_STAGE_KEY}) to give an electrical stage"
        )
    source = doc.component(sources[0])
    if source["params"].get("domain") != "rotational":
        raise LookupError(f"{doc.source}: plant.{sources[0]} drives no motor (not rotational)")
    pole_pairs = (doc.data.get(ANALYSIS_SECTION) or {}).get(POLE_PAIRS_KEY)
    if not isinstance(pole_pairs, int) or isinstance(pole_pairs, bool) or pole_pairs < 1:
        raise LookupError(
            f"{doc.source}: {ANALYSIS_SECTION}.{POLE_PAIRS_KEY} = {pole_pairs!r}: the motor's "
            "pole pairs are needed for its electrical stage"
        )
    k_t = float(source["params"]["gain"])
    data = copy.deepcopy(doc.data)
    data["plant"] = _plant(data["plant"], sources[0], stage, k_t, pole_pairs)
    data["controller"] = _controller(data["controller"], stage, k_t, pole_pairs)
    data["engine"] = {**(data.get("engine") or {}), "substeps": _substeps(stage)}
    return ModelDoc(
        data=data,
        source=doc.source,
        ties=doc.ties,
        asymmetric=doc.asymmetric,
        reference_gain=doc.reference_gain or k_t,
    )


def current_answer(stage: DriveStage, t_s: FloatArray) -> Callable[[FloatArray], FloatArray]:
    """The current loop's answer to a voltage error d on the windings, sampled at t_s: with the
    PI u = Kp (e + (1/Ti) int e) on L di/dt = u - R i + d (back-EMF aside), the current leaves
    its setpoint by
        i(s) / d(s) = s / (L s^2 + (R + Kp) s + Kp / Ti),
    a dip the integrator removes over about Ti (R + Kp) / Kp (the one-period computation delay
    and the velocity loop's answer aside)."""
    from scipy.signal import lsim  # pyright: ignore[reportMissingTypeStubs, reportUnknownVariableType]

    system = ([1.0, 0.0], [stage.L_H, stage.R_s_ohm + stage.Kp_V_A, stage.Kp_V_A / stage.Ti_s])
    t = np.asarray(t_s, dtype=float) - float(t_s[0])
    # the voltages asked for are the dead time's signature at each i_reg of the record's
    # current, the same in every ranking of a diagnosis; lsim steps its state sample by sample
    # in Python (0.05 s on 13 000 samples), and asked again in every round it was 2.3 s of a
    # 3.8 s diagnosis (10 i_reg, 4-5 rankings)
    answers: dict[bytes, FloatArray] = {}

    def answer(volts: FloatArray) -> FloatArray:
        u = np.asarray(volts, dtype=float)
        key = u.tobytes()
        if key not in answers:
            if len(answers) >= MAX_ANSWERS:
                answers.clear()
            _, y, _ = lsim(system, u, t)  # pyright: ignore[reportUnknownVariableType]
            answers[key] = np.asarray(y, dtype=float)
            answers[key].flags.writeable = False  # shared by every caller
        return answers[key]

    return answer


def dead_time_edit(doc: ModelDoc, cand: Weights, inverter_edit: EditFn) -> Edit:
    """The Inverter's dead-time edit on the expanded model, started halfway up and bounded by
    the largest dead time the sub-steps were chosen for."""
    edit = inverter_edit(expand(doc), cand)
    (own,) = edit.own
    start = START_SHARE * MAX_DEAD_FRACTION
    own = dataclasses.replace(own, initial=start, scale=start, upper=MAX_DEAD_FRACTION)
    fitted = model_of(edit.doc).set(own.name, start)
    # the stage changes the twin at any dead time (its current loop lags): the dead time is
    # tested against the stage without it
    edit = make_edit(fitted, [own], edit.report, interacts=False)
    return dataclasses.replace(edit, restructures=True)


def _plant(
    plant: dict[str, Any], name: str, stage: DriveStage, k_t: float, pole_pairs: int
) -> dict[str, Any]:
    current_limit = 1000.0
    motor = {
        "name": name,
        "type": "Pmsm",
        "params": {
            "R_s": stage.R_s_ohm,
            "L_d": stage.L_H,
            "L_q": stage.L_H,
            "psi_pm": k_t / (1.5 * pole_pairs),
            "p": pole_pairs,
            "R_fe": None,
            "J": ROTOR_J,
            "T_c": 0.0,
            "b": 0.0,
            "omega_reg": 0.01,
            "i_max": current_limit,
            # the currents decay over a few current-loop periods with the inverter off
            "T_open": 4.0 * stage.current_period_s,
        },
    }
    electrical = [
        {"name": f"{name}_bus", "type": "DcBus", "params": {"u_0": stage.u_dc_V, "R_i": 0.0}},
        {
            "name": f"{name}_inverter",
            "type": "Inverter",
            "params": {
                "model": "averaged",
                "f_pwm": stage.f_pwm_Hz,
                "t_dead": 0.0,
                "u_f": 0.0,
                "i_reg": stage.i_reg_A,
            },
        },
        {
            "name": f"{name}_current_sensor",
            "type": "CurrentSensor",
            "params": {
                "gain": 1.0,
                "offset": 0.0,
                "noise_std": 0.0,
                "adc_bits": 24,
                "range_A": current_limit,
                "delay_ticks": 0,
            },  # fmt: skip
        },
    ]
    components = [motor if e["name"] == name else e for e in plant["components"]] + electrical
    connect = plant["connect"] + [
        [f"{name}_bus.dc", f"{name}_inverter.dc"],
        [f"{name}_inverter.ac", f"{name}.ac"],
        [f"{name}_current_sensor.ac", f"{name}.ac"],
    ]
    return {**plant, "components": components, "connect": connect}


def _controller(
    controller: dict[str, Any], stage: DriveStage, k_t: float, pole_pairs: int
) -> dict[str, Any]:
    out = copy.deepcopy(controller)
    out["base_period_s"] = stage.current_period_s
    out["computation_delay"] = True  # the loop's voltage applies from its next sample
    out["current"] = {
        "period_s": stage.current_period_s,
        "pole_pairs": pole_pairs,
        "R_s_ohm": stage.R_s_ohm,
        "L_d_H": stage.L_H,
        "L_q_H": stage.L_H,
        "psi_pm_Vs": k_t / (1.5 * pole_pairs),
        "Kp_d_V_A": stage.Kp_V_A,
        "Ti_d_s": stage.Ti_s,
        "Kp_q_V_A": stage.Kp_V_A,
        "Ti_q_s": stage.Ti_s,
        "decoupling": stage.decoupling,
        "back_emf_ff": stage.back_emf_ff,
    }
    return out


def _substeps(stage: DriveStage) -> int:
    """RK4 sub-steps for the stiffest dead time the fit may reach: near zero current the
    voltage error's slope u_dc MAX_DEAD_FRACTION / i_reg acts as a resistance in series with
    the windings (3/2 of it in the rotor frame), a real pole at R / L."""
    r_dead = 1.5 * stage.u_dc_V * MAX_DEAD_FRACTION / stage.i_reg_A
    rate = (stage.R_s_ohm + r_dead) / stage.L_H
    return max(
        1, 2 ** math.ceil(math.log2(max(1.0, stage.current_period_s * rate / RK4_REAL_LIMIT)))
    )
