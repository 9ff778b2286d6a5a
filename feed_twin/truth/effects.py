"""Hidden effects of the truth machine: how each sets the machine, its typical size, its draw.

Each effect is named as the discrepancy workflow's library names it (feed_twin.plant.registry)
and given by the values the workflow reports for it (its report keys, e.g. `F_c_N`), so that a
fitted parameter compares with the truth directly. The values are of the twin parameter, not of
the deviation: `coulomb_friction: {F_c_N: 150}` is a machine whose Coulomb force is 150 N where
the data sheet (and the nominal twin, config/truth_nominal.yaml) says 60 N.

`draw(name, rng)` picks a size factor f uniformly in [0.5, 2] times the TYPICAL deviation:
    coulomb_friction         F_c = 60 + 60 f N (sliding force per direction)
    viscous_friction         F_v = 300 + 300 f N s/m
    stribeck_friction        dF_s = 40 f N, v_s = 5 f' mm/s (f' its own draw)
    asymmetric_friction      F_v_pos = 300 + 150 f, F_v_neg = 300 - 75 f N s/m
    constant_force           an unbalanced hanging mass of 15 f kg: f_0 = -15 f g N
    mass_error               table + load 150 + 100 f kg (m_kg: the table mass)
    torque_constant_error    K_t off by +-8 f % (sign drawn)
    measurement_delay        the loops' position 1-4 ms late (delay_s: round(2 f) ms, >= 1)
    stiction                 Karnopp sticking of the data sheet's Coulomb friction: held at rest
                             (below 10 um/s) up to the sliding force, F_hold = 60 N. No size:
                             on or off. Drawn as a sticking Coulomb force of 60 (1 + 0.5 f) N,
                             the record is a Coulomb change too, and coulomb_friction was named
                             first with stiction beside it 8-9 % low; a break-away above the
                             sliding force (F_hold 90 N on 60 N) barely shows on this program
                             (its dwells end before the loop's integrator winds up to it:
                             effort residual 0.0146 A against 0.0138 A at 60 N), and the
                             library's stiction, like this truth's, holds with its sliding force
    backlash                 10 f um of lost motion between nut and table
    lead_error               3 f um once per screw revolution, phase uniform
    position_dependent_stiffness   bearing stiffness and EA both / (1 + f)
    thermal_drift            2 f K per metre travelled
    cogging_torque           0.05 f N m, 6 per motor revolution, phase uniform
    current_offset           +-0.1 f A on each phase sensor (signs drawn)
    dead_time                1 f us
and, beyond the library (a change over the record, for the drift detection):
    friction_drift           Coulomb and viscous friction grow by 3 f % per second
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping

import numpy as np

from feed_twin.truth.machine import G_N_KG, NOMINAL, Machine

Sizes = dict[str, float]
SIZE_RANGE = (0.5, 2.0)  # size factors are drawn uniformly in this range


def _coulomb(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, F_c_pos=p["F_c_N"], F_c_neg=p["F_c_N"])


def _viscous(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, F_v_pos=p["F_v_N_s_m"], F_v_neg=p["F_v_N_s_m"])


def _stribeck(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, dF_s=p["dF_s_N"], v_s=p["v_s_m_s"])


def _asymmetric(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, F_v_pos=p["F_v_pos"], F_v_neg=p["F_v_neg"])


def _constant(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, m_unbalanced=-p["f_0_N"] / G_N_KG)


def _mass(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, m_table=p["m_kg"])


def _gain(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, kt_scale=p["gain"] / NOMINAL.K_t)


def _delay(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, feedback_delay_s=p["delay_s"])


def _stiction(mc: Machine, p: Mapping[str, float]) -> Machine:
    f = p["F_hold_N"]
    return dataclasses.replace(mc, F_hold=f, F_c_pos=f, F_c_neg=f)


def _backlash(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, backlash=p["gap_m"])


def _lead(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, lead_error_m=p["amplitude_m"], lead_error_phase=p["phase_rad"])


def _stiffness(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, k_bearing=p["k_bearing_N_m"], EA=p["EA_N"])


def _thermal(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, heating_K_m=p["heating_K_m"])


def _cogging(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(
        mc,
        cogging_order=int(p["order"]),
        cogging_Nm=p["amplitude_Nm"],
        cogging_phase=p["phase_rad"],
    )


def _offsets(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(
        mc, offset_a=p["offset_a_A"], offset_b=p["offset_b_A"], offset_c=p["offset_c_A"]
    )


def _dead_time(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, t_dead=p["t_dead_s"])


def _drift(mc: Machine, p: Mapping[str, float]) -> Machine:
    return dataclasses.replace(mc, friction_drift_per_s=p["rate_per_s"])


def _phase(rng: np.random.Generator) -> float:
    return float(rng.uniform(-math.pi, math.pi))


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


# name -> (how it sets the machine, how its sizes are drawn from a size factor f and the rng)
Apply = Callable[[Machine, Mapping[str, float]], Machine]
Draw = Callable[[float, np.random.Generator], Sizes]
EFFECTS: dict[str, tuple[Apply, Draw]] = {
    "coulomb_friction": (_coulomb, lambda f, r: {"F_c_N": 60.0 + 60.0 * f}),
    "viscous_friction": (_viscous, lambda f, r: {"F_v_N_s_m": 300.0 + 300.0 * f}),
    "stribeck_friction": (
        _stribeck,
        lambda f, r: {"dF_s_N": 40.0 * f, "v_s_m_s": 0.005 * float(r.uniform(*SIZE_RANGE))},
    ),
    "asymmetric_friction": (
        _asymmetric,
        lambda f, r: {"F_v_pos": 300.0 + 150.0 * f, "F_v_neg": 300.0 - 75.0 * f},
    ),
    "constant_force": (_constant, lambda f, r: {"f_0_N": -15.0 * f * G_N_KG}),
    "mass_error": (_mass, lambda f, r: {"m_kg": NOMINAL.m_table + 100.0 * f}),
    "torque_constant_error": (
        _gain,
        lambda f, r: {"gain": NOMINAL.K_t * (1.0 + 0.08 * f * _sign(r))},
    ),
    # in seconds, not in the twin's ticks: the workflow reports both, and a twin's tick is its own
    "measurement_delay": (_delay, lambda f, r: {"delay_s": 1e-3 * max(1, round(2.0 * f))}),
    "stiction": (_stiction, lambda f, r: {"F_hold_N": NOMINAL.F_c_pos}),
    "backlash": (_backlash, lambda f, r: {"gap_m": 10e-6 * f}),
    "lead_error": (_lead, lambda f, r: {"amplitude_m": 3e-6 * f, "phase_rad": _phase(r)}),
    "position_dependent_stiffness": (
        _stiffness,
        lambda f, r: {"k_bearing_N_m": NOMINAL.k_bearing / (1 + f), "EA_N": NOMINAL.EA / (1 + f)},
    ),
    "thermal_drift": (_thermal, lambda f, r: {"heating_K_m": 2.0 * f}),
    "cogging_torque": (
        _cogging,
        lambda f, r: {"order": 6.0, "amplitude_Nm": 0.05 * f, "phase_rad": _phase(r)},
    ),
    "current_offset": (
        _offsets,
        lambda f, r: {f"offset_{ph}_A": 0.1 * f * _sign(r) for ph in "abc"},
    ),
    "dead_time": (_dead_time, lambda f, r: {"t_dead_s": 1e-6 * f}),
    "friction_drift": (_drift, lambda f, r: {"rate_per_s": 0.03 * f}),
}


def _known(name: str) -> None:
    if name not in EFFECTS:
        raise ValueError(
            f"effect {name!r} is not one the truth machine has; one of {sorted(EFFECTS)}"
        )


def draw(name: str, rng: np.random.Generator) -> Sizes:
    """Sizes of effect `name` at a size factor drawn uniformly in SIZE_RANGE."""
    _known(name)
    return EFFECTS[name][1](float(rng.uniform(*SIZE_RANGE)), rng)


def draw_all(names: tuple[str, ...] | list[str], seed: int) -> dict[str, Sizes]:
    """Sizes of each named effect, drawn in order from one generator seeded with `seed`."""
    rng = np.random.default_rng(seed)
    return {name: draw(name, rng) for name in names}


def machine_with(hidden: Mapping[str, Mapping[str, float]], base: Machine = NOMINAL) -> Machine:
    """`base` with each hidden effect set to its sizes (applied in the mapping's order)."""
    mc = base
    for name, sizes in hidden.items():
        _known(name)
        mc = EFFECTS[name][0](mc, sizes)
    return mc
