"""The nominal model at the record's scale: what a slow record can tell, simulated at its cost.

A monitoring log samples every 10-1000 ms. It cannot show a 16 kHz current loop (its closed
loop settles within a millisecond), the modes of a coupling, a screw in torsion or the axial
springs (100 Hz and up, where a 10 Hz record's Nyquist frequency is 5 Hz), nor a backlash gap
below its position resolution. Simulated as written, a full axis model costs 16 000 ticks per
second of record for each parameter set (config/axis_default.yaml on the 105 s mill log: 1.7
million ticks, about a second, and the workflow simulates hundreds of sets). `reduce` writes
the same axis as the record sees it:

- the electrical drive is the ideal source of its torque (an EffortSource loses its drive's
  current loop, plant.current_loop): a Pmsm becomes its rotor (an Inertia
  of its J, same name) driven by an EffortSource of its torque constant K_t = 1.5 p psi_pm
  [N m/A], so the controller's current setpoint is the current the torque needs (the twin's
  effort is still `current_q_A`: `analysis.effort_signal`); DcBus, Inverter and CurrentSensor
  go. The rotor's own bearing friction (T_c, b) moves to the table as a GuideFriction of the
  same current, through the screw's force per torque while driving;
- an elastic two-port (Coupling, ScrewShaft, AxialCompliance; a Backlash whose gap is below the
  record's resolution) is rigid: its two ports are one node, and the inertia it carries stays
  (a ScrewShaft: an Inertia of its J). On an axis without an electrical drive whose springs the
  step resolves in one RK4 step they stay: rigid saves nothing there;
- the model runs at the NC's interpolation period (the command has nothing finer): no current
  loop and no computation delay (the closed current loop lags a fifth of that step), the
  position and velocity loops at that period with the velocity loop re-tuned as the
  controller node re-tunes it for its exchange (nodeset.controller_core), but keeping the
  drive's own Kp and Ti where they lie within the re-tuned ones; sensor delays are
  counted again in the new ticks (the same time: a fraction of a tick is interpolated). Rigid,
  the axis is one body and allows that step (the friction's stiff sign at rest takes the RK4
  sub-steps Twin.compile chooses);
- a lossy screw (which needs a massless flange, so a spring behind it) becomes lossless with
  its efficiency moved to the motor's side (`_lossless`).

The reduction is checked on each record before it is used (`at_record_scale`): the full model
and the reduced one are simulated once on the record's command, and the reduced one is used
only if its position stays within half the record's resolution of the full one's and its
effort within EFFORT_AGREEMENT of the full effort's RMS; otherwise the full model is kept and
the report says why.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from feed_twin.analysis.model_doc import (
    ANALYSIS_SECTION,
    EFFORT_SIGNAL_KEY,
    POLE_PAIRS_KEY,
    ModelDoc,
)
from feed_twin.analysis.twin import SLOW_COMMAND_S, Twin, drive_from_run
from feed_twin.analysis.visibility import unresolved
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import MeasuredRun
from feed_twin.plant.ball_screw import BallScrew
from feed_twin.plant.effort_source import CURRENT_LOOP_FIELDS, EffortSource

# the electrical drive: gone at the record's scale (the motor becomes a torque source)
DRIVE_TYPES = ("DcBus", "Inverter", "CurrentSensor")
# elastic two-ports whose ports become one node (Backlash only below the record's resolution)
ELASTIC_TYPES = ("Coupling", "ScrewShaft", "AxialCompliance")
TORSIONAL_TYPES = ("Coupling", "ScrewShaft")
SENSOR_TYPES = ("Encoder", "LinearScale")
# the reduced twin's effort may differ from the full twin's by this share of the full effort's
# RMS: a fifth of the 10 % within which the workflow names an effect
EFFORT_AGREEMENT = 0.02
# a runaway of the reduced drive's torque: this many times the torque of the current limit
RUNAWAY_FACTOR = 10.0
MOTOR_FRICTION_V_S = 1e-3  # [m/s] Stribeck speed of the rotor's friction (no Stribeck excess)


@dataclass(frozen=True, kw_only=True)
class Agreement:
    """How far the reduced twin's response lies from the full twin's on one record."""

    position_max_m: float  # largest difference of the positions at the record's samples
    effort_rms: float  # RMS difference of the efforts [effort SI unit]
    effort_share: float  # effort_rms over the full twin's effort RMS
    full_s: float  # [s] wall time of one simulation of the full model
    reduced_s: float  # [s] ... and of the reduced one

    def holds(self, resolution_m: float) -> bool:
        return self.position_max_m <= 0.5 * resolution_m and self.effort_share <= EFFORT_AGREEMENT


def reduce(doc: ModelDoc, *, resolution_m: float) -> tuple[ModelDoc | None, list[str]]:
    """The model at its NC period, rigid and driven by an ideal torque source (module
    docstring), and one line per change; (None, [reason]) when there is nothing to reduce (the
    model runs at that period already and has no current loop) or it cannot be reduced."""
    step = _record_step(doc)
    kinds = {e["type"] for e in doc.data["plant"]["components"]}
    if doc.base_period() >= step * (1.0 - 1e-9) and not kinds & {"Pmsm", *DRIVE_TYPES}:
        return None, ["the model runs at its NC period already"]
    if "DcMotor" in kinds:
        return None, ["a DcMotor's voltage drive is not reduced to a torque source"]
    try:
        limit = float(doc.data["controller"]["drive"]["effort_limit"])
        plant, changes = _plant(doc, step, limit, resolution_m, rigid=ELASTIC_TYPES)
        if not kinds & {"Pmsm", *DRIVE_TYPES}:
            # a torque-source axis whose springs the step resolves in one RK4 step gains
            # nothing from making them rigid: they stay (rigid, the truth machine's nominal
            # twin named an asymmetric friction for a Coulomb force and a weight on 10 Hz logs
            # that its compliant model at the same step named right); a torsional spring the
            # step does not resolve (its coupling's 1.1 kHz mode) is made rigid alone first
            for rigid in ((), TORSIONAL_TYPES):
                elastic, kept = _plant(doc, step, limit, resolution_m, rigid=rigid)
                if _resolved(elastic, step, doc.source):
                    plant, changes = elastic, kept
                    break
        screws = doc.of_type(BallScrew.TYPE)
        eta = doc.get(f"{screws[0]}.efficiency") if len(screws) == 1 else 1.0
        if eta < 1.0:
            plant, moved = _lossless(plant, eta)
            changes += moved
        controller, tuned = _controller(doc, step)
    except (ConfigError, LookupError, ValueError) as exc:
        return None, [f"cannot be reduced: {exc}"]
    data = copy.deepcopy(doc.data)
    data["plant"], data["controller"] = plant, controller
    if "engine" in data:
        data["engine"] = {**data["engine"], "base_period_s": step, "substeps": 1}
    motors = doc.of_type("Pmsm")
    if motors:
        analysis = dict(data.get(ANALYSIS_SECTION) or {})
        analysis[EFFORT_SIGNAL_KEY] = "current_q_A"
        analysis.setdefault(POLE_PAIRS_KEY, int(doc.component(motors[0])["params"]["p"]))
        data[ANALYSIS_SECTION] = analysis
    # the recorded effort's conversion stays the model's (an EffortSource's gain: without it
    # the reduced twin's effort came out in the drive's unit, 1/K_t of the full one's)
    reduced = ModelDoc(data=data, source=doc.source, reference_gain=doc.reference_gain)
    step_ms = f"{doc.base_period() * 1e3:.4g} ms -> {step * 1e3:.4g} ms"
    return reduced, [f"step {step_ms} (no current loop)", *changes, *tuned]


def _record_step(doc: ModelDoc) -> float:
    """[s] The reduced model's step: the NC's interpolation period (the command has nothing
    finer, and a 10 Hz record samples every hundredth of it)."""
    return float(doc.data["controller"].get("nc_period_s", doc.base_period()))


def _controller(doc: ModelDoc, step: float) -> tuple[dict[str, Any], list[str]]:
    """The controller section at `step`, without its current loop: its position and velocity
    loops at `step`, the velocity loop re-tuned and the position gain capped as the controller
    node does for an exchange of that period (nodeset.controller_core); no computation delay
    (the closed current loop it stood for lags a fraction of the step)."""
    from feed_twin.control.config import load_controller_config
    from feed_twin.nodeset.controller_core import controller_node_config

    config = load_controller_config(doc.data["controller"], source=doc.source)
    derived, notes = controller_node_config(config, step)
    notes = [n for n in notes if "capped" in n]
    out = copy.deepcopy(doc.data["controller"])
    out.pop("current", None)
    out["base_period_s"] = step
    out["computation_delay"] = False
    for name, keys in (("position", ("Kv_1_s",)), ("velocity", ("Kp", "Ti_s"))):
        loop = getattr(derived, name)
        if loop is not None:
            out[name]["period_s"] = loop.period_s
            out[name].update({k: float(getattr(loop, k)) for k in keys})
    own, tuned = config.velocity, derived.velocity
    if own is not None and tuned is not None and tuned.Ti_s is not None:
        # the drive's own gains where they lie within the re-tuned ones (a Kp no higher, an
        # integral no faster): they are stable at the step and answer as the machine does (the
        # truth machine's 4 kHz loop, re-tuned for 1 ms, got Ti 8 ms for its 16 ms, and its
        # 10 Hz records named an asymmetric friction for a Coulomb force and a weight)
        Kp = min(own.Kp, tuned.Kp)
        Ti = tuned.Ti_s if own.Ti_s is None else max(own.Ti_s, tuned.Ti_s)
        out["velocity"].update({"Kp": Kp, "Ti_s": Ti})
        if (Kp, Ti) != (own.Kp, own.Ti_s):
            notes.append(
                f"velocity loop re-tuned for the step: Kp {own.Kp:g} -> {Kp:.4g}, "
                f"Ti {own.Ti_s!r} -> {Ti:.4g} s"
            )
    return out, notes


def _resolved(plant: dict[str, Any], step: float, source: str) -> bool:
    """The plant section's modes need no RK4 sub-step at `step` (Twin.compile's rule)."""
    from feed_twin.analysis.twin import substeps_needed
    from feed_twin.plant.config import load_plant

    model = load_plant(plant, source=source)
    try:
        return substeps_needed(model, model.nominal_params(), step) == 1
    except ConfigError:  # no sub-step count makes it stable
        return False


def _plant(
    doc: ModelDoc,
    step: float,
    effort_limit: float,
    resolution_m: float,
    *,
    rigid: tuple[str, ...],
) -> tuple[dict[str, Any], list[str]]:
    """The plant section, torque-driven, with its two-ports of the types `rigid` rigid
    (module docstring), and what changed."""
    ratio = doc.base_period() / step
    parent: dict[str, str] = {}

    def root(port: str) -> str:
        while parent.get(port, port) != port:
            port = parent[port]
        return port

    def join(a: str, b: str) -> None:
        parent[root(a)] = root(b)

    kept: list[dict[str, Any]] = []
    extra: list[tuple[dict[str, Any], str]] = []  # (component, a port of its node)
    changed: list[str] = []
    table = doc.table_port()
    for entry in doc.data["plant"]["components"]:
        name, kind, params = entry["name"], entry["type"], entry["params"]
        if kind in DRIVE_TYPES:
            changed.append(f"{name} ({kind}) removed")
        elif kind == "Pmsm":
            kept.append({"name": name, "type": "Inertia", "params": {"J": float(params["J"])}})
            extra += _motor(doc, name, effort_limit, table)
            changed.append(
                f"{name} (Pmsm) -> rotor inertia + torque source of K_t"
                + (" (its cogging dropped)" if params.get("cogging") else "")
            )
        elif kind in rigid or (kind == "Backlash" and float(params["gap"]) < resolution_m):
            join(f"{name}.a", f"{name}.b")
            j = _carried_inertia(entry)
            if j > 0.0:
                extra.append(({"name": name, "type": "Inertia", "params": {"J": j}}, f"{name}.a"))
            changed.append(f"{name} ({kind}) rigid")
        else:
            kept.append(_kept(entry, ratio))
    ports = {f"{e['name']}.{p}" for e, _ in extra for p in _ports(e)}
    ports |= {f"{e['name']}.{p}" for e in kept for p in _ports(e)}
    for a, b in doc.data["plant"]["connect"]:
        join(a, b)
    for entry, at in extra:
        join(f"{entry['name']}.flange", at)
    nodes: dict[str, list[str]] = {}
    named = [p for pair in doc.data["plant"]["connect"] for p in pair]
    named += [f"{e['name']}.flange" for e, _ in extra]
    for port in dict.fromkeys(named):
        if port in ports:
            nodes.setdefault(root(port), []).append(port)
    connect = [[members[0], other] for members in nodes.values() for other in members[1:]]
    components = kept + [e for e, _ in extra]
    return {**doc.data["plant"], "components": components, "connect": connect}, changed


def _kept(entry: dict[str, Any], ratio: float) -> dict[str, Any]:
    """A component that stays, at the new step (`ratio`: old step over new): a sensor's delay
    the same time in the new ticks; an EffortSource an ideal source, its drive's current loop gone
    with the step ("no current loop"; its fast pole would need RK4 sub-steps there)."""
    entry = copy.deepcopy(entry)
    if entry["type"] == EffortSource.TYPE:
        for field in CURRENT_LOOP_FIELDS:
            entry["params"].pop(field, None)
    if entry["type"] in SENSOR_TYPES:
        # the same time in the new ticks, a fraction of one interpolated
        entry["params"]["delay_ticks"] = float(entry["params"]["delay_ticks"]) * ratio
    return entry


def _lossless(plant: dict[str, Any], eta: float) -> tuple[dict[str, Any], list[str]]:
    """The plant with its one lossy screw lossless and the loss moved to the motor's side: the
    torque source's gain and every rotor inertia times the efficiency eta. While the motor
    drives the table (friction, weight lifted, accelerating) that is exact: the table's force
    F needs the current F lead / (2 pi eta K_t) in both, the rotor's own torque J alpha / K_t.
    Where the table's inertia drives the motor back (braking) the full model passes eta F, this
    one F / eta: 19 % of that force at eta = 0.9, within the samples next to an acceleration a
    slow record does not resolve. A rigid screw then needs no spring (a lossy screw needs a
    massless flange), and the whole axis is one body."""
    for entry in plant["components"]:
        params = entry["params"]
        if entry["type"] == BallScrew.TYPE:
            params["efficiency"] = 1.0
        elif entry["type"] == "EffortSource" or entry["type"] == "Inertia":
            key = "gain" if entry["type"] == "EffortSource" else "J"
            params[key] = float(params[key]) * eta
    return plant, [
        f"the screw's efficiency {eta:g} moved to the motor's side (torque and rotor inertias "
        f"x {eta:g}; exact while the motor drives the table)"
    ]


def _carried_inertia(entry: dict[str, Any]) -> float:
    """[kg m^2] The inertia an elastic two-port lumps at its ports (a ScrewShaft's J), which
    stays on the node its ports become."""
    from feed_twin.plant.registry import COMPONENT_TYPES

    component = COMPONENT_TYPES[entry["type"]](**entry["params"])
    slots = component.slots()
    total = 0.0
    for spec in component.inertias():
        if component.ports()[spec.port] != "rotational":
            raise ValueError(f"{entry['name']}: a translational inertia of an elastic element")
        total += spec.factor * slots[spec.slot]
    return total


def _ports(entry: dict[str, Any]) -> tuple[str, ...]:
    from feed_twin.plant.registry import COMPONENT_TYPES

    kind = COMPONENT_TYPES[entry["type"]]
    if entry["type"] == "EffortSource":
        return ("flange",)
    return tuple(kind.PORTS)


def _motor(
    doc: ModelDoc, name: str, effort_limit: float, table: str
) -> list[tuple[dict[str, Any], str]]:
    """The torque source of a Pmsm `name` and its rotor's friction at the table."""
    params = doc.component(name)["params"]
    k_t = doc.get(f"{name}.K_t")
    source = {
        "name": f"{name}_torque",
        "type": "EffortSource",
        "params": {
            "domain": "rotational",
            "gain": k_t,
            "T_lag": 0.0,
            "f_max": RUNAWAY_FACTOR * k_t * effort_limit,
        },
    }
    out = [(source, f"{name}.flange")]
    t_c, b = float(params.get("T_c", 0.0)), float(params.get("b", 0.0))
    if params.get("R_fe"):
        # the iron loss draws i_fe = p omega psi_pm / R_fe beside the torque's current: a
        # viscous torque of K_t p psi_pm / R_fe in the current the drive reports
        b += k_t * int(params["p"]) * float(params["psi_pm"]) / float(params["R_fe"])
    screws = doc.of_type(BallScrew.TYPE)
    if (t_c > 0.0 or b > 0.0) and screws:
        lead = doc.get(f"{screws[0]}.lead")
        screw = BallScrew(lead=lead, efficiency=doc.get(f"{screws[0]}.efficiency"))
        per_torque = screw.force_per_torque(resisting=True)
        f_c = t_c * per_torque
        f_v = b * (2.0 * math.pi / lead) * per_torque
        friction = {
            "name": f"{name}_friction",
            "type": "GuideFriction",
            "params": {
                "F_c_pos": f_c,
                "F_c_neg": f_c,
                "F_v_pos": f_v,
                "F_v_neg": f_v,
                "dF_s": 0.0,
                "v_s": MOTOR_FRICTION_V_S,
                "v_reg": float(params["omega_reg"]) * lead / (2.0 * math.pi),
            },
        }
        out.append((friction, table))
    return out


def agreement(full: Twin, reduced: Twin, run: MeasuredRun, *, resolution_m: float) -> Agreement:
    """The two twins' nominal responses on the record's command, each sample the mean over
    its period (Twin.sample_means: a stick-slip of a few milliseconds is no evidence at 10 Hz;
    the same time span at either twin's tick, not the last dec ticks, whose half-tick offset
    put a 1 ms twin 0.375 ms ahead of its 0.25 ms original, 56 um at 150 mm/s), compared
    where the command moves, but next to an acceleration the record does not resolve
    (visibility.unresolved: where a move starts within a sample, a fraction of a millisecond
    of either twin's loop delays puts the sample before or after the start). At rest the
    force held is any within the friction's breakaway (the full twin's rotor holds its bearing
    friction through the coupling's windup a sample longer): not compared."""
    import time

    drive = drive_from_run(run)
    v = np.gradient(drive.pos_ref_m, run.sample_period_s)
    on = ~unresolved(v, run.sample_period_s, resolution_m) & (v != 0.0)
    clock = time.perf_counter()
    a = full.sample_means(drive, full.nominal[None, :])
    full_s = time.perf_counter() - clock
    clock = time.perf_counter()
    b = reduced.sample_means(drive, reduced.nominal[None, :])
    reduced_s = time.perf_counter() - clock
    if not (a.ok[0] and b.ok[0]) or a.effort is None or b.effort is None:
        return Agreement(
            position_max_m=math.inf,
            effort_rms=math.inf,
            effort_share=math.inf,
            full_s=full_s,
            reduced_s=reduced_s,
        )
    de = (a.effort[0] - b.effort[0])[on]
    rms = float(np.sqrt(np.mean(de**2)))
    scale = float(np.sqrt(np.mean(a.effort[0][on] ** 2)))
    return Agreement(
        position_max_m=float(np.max(np.abs(a.x_m[0] - b.x_m[0])[on])),
        effort_rms=rms,
        effort_share=rms / scale if scale > 0.0 else math.inf,
        full_s=full_s,
        reduced_s=reduced_s,
    )


def at_record_scale(
    run: MeasuredRun, doc: ModelDoc, *, resolution_m: float
) -> tuple[ModelDoc, list[str]]:
    """The model the workflow simulates on `run`: `doc` reduced to the record's scale when the
    record is slower than SLOW_COMMAND_S and the reduced twin agrees with the full one on it
    (module docstring), else `doc`; and the lines that say which and why."""
    if run.sample_period_s <= SLOW_COMMAND_S:
        return doc, []
    reduced, changes = reduce(doc, resolution_m=resolution_m)
    if reduced is None:
        return doc, []
    full, small = Twin.compile(doc), Twin.compile(reduced)
    agree = agreement(full, small, run, resolution_m=resolution_m)
    figures = (
        f"position within {agree.position_max_m * 1e6:.3g} um, effort within "
        f"{100 * agree.effort_share:.2g} % RMS of the full model's, one simulation "
        f"{agree.full_s:.2g} s -> {agree.reduced_s:.2g} s"
    )
    if not agree.holds(resolution_m):
        return doc, [
            f"the model at the record's scale does not agree with the full one ({figures}; "
            f"needed: half the resolution, {100 * EFFORT_AGREEMENT:g} %): the full model is "
            "simulated"
        ]
    said = ", ".join(c for c in changes if c)
    return reduced, [
        f"model at the record's scale (what a {1.0 / run.sample_period_s:.3g} Hz record can "
        f"show): {said}; checked on this record against the full model: {figures}"
    ]


__all__ = ["EFFORT_AGREEMENT", "Agreement", "agreement", "at_record_scale", "reduce"]
