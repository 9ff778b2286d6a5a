"""The workflow's only door to the integrated model: model documents and batch simulation.

`ModelDoc` is a model YAML (the `plant:` and `controller:` sections of feed_twin.plant.config
and feed_twin.control.cascade) held as data, with the edits the effect library needs: set a
parameter, tie two slots to one fitted value, add a component, write the augmented file. Edits
return new documents; the nominal file is never touched.

`Twin` compiles a document once (the plant's assembler and engine, the controller's cascade)
and simulates N parameter sets at once with `run_batch`, driven by a measured run's command and
known disturbances. What it returns is what the measurement system of the real axis reports: the
position as the controller's feedback sensor sees it, the drive effort in the measured
effort's SI unit and, for a PMSM axis, the q-axis voltage the current controller commands
(`out.u_q_ref_V`, before the dead-time compensation: what a drive scope records as u_q).

Why the diagnosis twin measures without quantisation: with the encoder's real count the
simulated position, and through the loop the effort, are piecewise constant in the parameters,
so finite-difference Jacobians of an output-error fit are zero or random. The twin used for
fitting sets the step of every Encoder and LinearScale to 1e-12 of a revolution or metre (the
quantisation noise is in the measurement, not in what the model should explain). The same holds
for the phase-current ADC: the fitting twin's CurrentSensor has neither rounding nor noise.
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from feed_twin.analysis.fit import SimOutputs
from feed_twin.core import signals
from feed_twin.io.config import ConfigError, load_yaml
from feed_twin.io.measured import MeasuredDataError, MeasuredRun

_COGGING_SLOT = re.compile(r"^cog(\d+)_(order|amplitude|phase)$")  # Pmsm slots of a harmonic
# an axial compliance's engine slot EA is stored in the document as E with the root diameter
# fixed: fitting EA (one number) is what the position-dependent stiffness identifies
_AXIAL_RIGIDITY = "EA"
# an averaged Inverter's engine slot dead_fraction = t_dead * f_pwm (the duty the dead time
# removes) is stored in the document as t_dead: fitting it moves the averaged model's voltage
_DEAD_FRACTION = "dead_fraction"
SMOOTH_SENSOR_STEP = 1e-12  # [rad or m] sensor step of the fitting twin (see module docstring)
FIXED_SECTIONS = ("plant", "controller")
# the section the workflow writes beside a fitted model, and its key: the drive gain the
# measured effort was converted with (the nominal one), which a fitted gain must not replace
ANALYSIS_SECTION = "analysis"
REFERENCE_GAIN_KEY = "effort_reference_gain"
# the record's own slots (not the machine's): `analysis.effort_delay_s`, how much later than the
# position the recorder stamps the effort (trace side, outside every loop)
RECORD_SLOTS = ("effort_delay_s",)
EFFORT_DELAY_SLOT = f"{ANALYSIS_SECTION}.effort_delay_s"


@dataclass(frozen=True, kw_only=True, eq=False)
class ModelDoc:
    """A model YAML as data plus the ties between slots that the fit treats as one value."""

    data: dict[str, Any]
    source: str
    ties: tuple[tuple[str, tuple[str, ...]], ...] = ()
    asymmetric: tuple[str, ...] = ()  # GuideFriction components fitted per direction
    # the drive gain of the document the workflow started from: the measured effort was
    # converted with the nominal gain, so the twin's effort is too (even if the fit changes it)
    reference_gain: float | None = None

    @classmethod
    def load(cls, path: str | Path) -> ModelDoc:
        data = load_yaml(path)
        for key in FIXED_SECTIONS:
            if key not in data:
                raise ConfigError(f"{path}: missing required section {key}")
        doc = cls(data=data, source=str(path))
        g = doc.gain_slot()
        reference = None if g is None else doc.get(g)
        written = (data.get(ANALYSIS_SECTION) or {}).get(REFERENCE_GAIN_KEY)
        if written is not None:
            if not (isinstance(written, (int, float)) and math.isfinite(written) and written):
                raise ConfigError(
                    f"{path}: {ANALYSIS_SECTION}.{REFERENCE_GAIN_KEY} = {written!r}: must be a "
                    "finite number other than 0"
                )
            reference = float(written)
        return ModelDoc(data=data, source=str(path), reference_gain=reference)

    # ---------------------------------------------------------------- lookup

    def _components(self) -> list[dict[str, Any]]:
        return self.data["plant"]["components"]

    def component(self, name: str) -> dict[str, Any]:
        for entry in self._components():
            if entry.get("name") == name:
                return entry
        raise LookupError(f"{self.source}: no component named {name!r}")

    def of_type(self, kind: str) -> list[str]:
        return [e["name"] for e in self._components() if e.get("type") == kind]

    def mass_slot(self) -> str | None:
        masses = self.of_type("Mass")
        return f"{masses[-1]}.m" if masses else None

    def friction(self) -> str | None:
        found = self.of_type("GuideFriction")
        return found[0] if found else None

    def gain_slot(self) -> str | None:
        found = self.of_type("EffortSource")
        return f"{found[0]}.gain" if found else None

    def tie_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.ties)

    def ties_of(self, friction: str) -> str:
        return "asymmetric" if friction in self.asymmetric else "symmetric"

    def mark_asymmetric(self, friction: str) -> ModelDoc:
        return self._copy(asymmetric=self.asymmetric + (friction,))

    def tie_members(self, name: str) -> tuple[str, ...]:
        for tied, members in self.ties:
            if tied == name:
                return members
        return (name,)

    def has_slot(self, slot: str) -> bool:
        """True for a tie name or a parameter the document holds (not a split tie)."""
        if slot in self.tie_names():
            return True
        comp, _, field_name = slot.partition(".")
        if comp == ANALYSIS_SECTION:
            return field_name in (self.data.get(ANALYSIS_SECTION) or {})
        try:
            params = self.component(comp)["params"]
        except LookupError:
            return False
        harmonic = _COGGING_SLOT.match(field_name)
        if harmonic is not None:
            return int(harmonic.group(1)) < len(params.get("cogging", []))
        if field_name == _AXIAL_RIGIDITY:
            return "E" in params and "d_root" in params
        if field_name == _DEAD_FRACTION:
            return "t_dead" in params and "f_pwm" in params
        return field_name in params

    def get(self, slot: str) -> float:
        first = self.tie_members(slot)[0]
        comp, _, field_name = first.partition(".")
        if comp == ANALYSIS_SECTION and field_name in RECORD_SLOTS:
            return float((self.data.get(ANALYSIS_SECTION) or {}).get(field_name, 0.0))
        params = self.component(comp)["params"]
        harmonic = _COGGING_SLOT.match(field_name)
        if harmonic is not None:
            n, key = int(harmonic.group(1)), harmonic.group(2)
            return float(params.get("cogging", [])[n][key])
        if field_name == _AXIAL_RIGIDITY and "E" in params and "d_root" in params:
            return float(params["E"]) * math.pi * float(params["d_root"]) ** 2 / 4.0
        if field_name == _DEAD_FRACTION and "t_dead" in params and "f_pwm" in params:
            return float(params["t_dead"]) * float(params["f_pwm"])
        if field_name not in params:
            pair = (f"{field_name}_pos", f"{field_name}_neg")
            if all(p in params for p in pair):
                # a tie that a later edit split (Coulomb -> asymmetric): report the mean
                return 0.5 * (float(params[pair[0]]) + float(params[pair[1]]))
            raise LookupError(f"{self.source}: plant.{comp} has no parameter {field_name!r}")
        return float(params[field_name])

    # ---------------------------------------------------------------- edits

    def _copy(self, **changes: Any) -> ModelDoc:
        return ModelDoc(
            data=changes.get("data", copy.deepcopy(self.data)),
            source=self.source,
            ties=changes.get("ties", self.ties),
            asymmetric=changes.get("asymmetric", self.asymmetric),
            reference_gain=self.reference_gain,
        )

    def set(self, slot: str, value: float) -> ModelDoc:
        new = self._copy()
        for member in self.tie_members(slot):
            comp, _, field_name = member.partition(".")
            if comp == ANALYSIS_SECTION and field_name in RECORD_SLOTS:
                new.data.setdefault(ANALYSIS_SECTION, {})[field_name] = float(value)
                continue
            params = new.component(comp)["params"]
            harmonic = _COGGING_SLOT.match(field_name)
            if harmonic is not None:
                n, key = int(harmonic.group(1)), harmonic.group(2)
                entry = params["cogging"][n]
                entry[key] = int(round(value)) if key == "order" else float(value)
                continue
            if field_name == _AXIAL_RIGIDITY and "E" in params and "d_root" in params:
                params["E"] = float(value) / (math.pi * float(params["d_root"]) ** 2 / 4.0)
                continue
            if field_name == _DEAD_FRACTION and "t_dead" in params and "f_pwm" in params:
                params["t_dead"] = float(value) / float(params["f_pwm"])
                continue
            old = params.get(field_name)
            # whole-number fields (counts, delays in ticks) stay whole numbers in the YAML
            keep_int = isinstance(old, int) and not isinstance(old, bool)
            params[field_name] = int(round(value)) if keep_int else float(value)
        return new

    def set_raw(self, component: str, field_name: str, value: Any) -> ModelDoc:
        """Set a component field that is not a fitted slot (a period, a flag)."""
        new = self._copy()
        new.component(component)["params"][field_name] = value
        return new

    def tie(self, name: str, members: tuple[str, ...]) -> ModelDoc:
        """Treat `members` as one parameter `name` (set to their mean now)."""
        if name in dict(self.ties):
            return self
        mean = sum(self.get(m) for m in members) / len(members)
        new = self._copy(ties=self.ties + ((name, members),))
        return new.set(name, mean)

    def untie(self) -> ModelDoc:
        return self._copy(ties=())

    def add_component(self, entry: dict[str, Any], connect_to: str) -> ModelDoc:
        """Append a component and connect its `flange` to the port `connect_to`."""
        new = self._copy()
        new.data["plant"]["components"].append(copy.deepcopy(entry))
        new.data["plant"]["connect"].append([f"{entry['name']}.flange", connect_to])
        return new

    def table_port(self) -> str:
        slot = self.mass_slot()
        if slot is None:
            raise LookupError(f"{self.source}: the model has no Mass (table) to act on")
        return f"{slot.split('.')[0]}.flange"

    def _free_name(self, base: str) -> str:
        taken = {e["name"] for e in self._components()}
        name, i = base, 2
        while name in taken:
            name, i = f"{base}{i}", i + 1
        return name

    def with_friction(self) -> ModelDoc:
        """The document with a GuideFriction on the table (all zero) if it has none."""
        if self.friction() is not None:
            return self
        entry = {
            "name": self._free_name("friction"),
            "type": "GuideFriction",
            "params": {
                "F_c_pos": 0.0,
                "F_c_neg": 0.0,
                "F_v_pos": 0.0,
                "F_v_neg": 0.0,
                "dF_s": 0.0,
                "v_s": 0.005,
                "v_reg": 1e-3,
            },
        }
        return self.add_component(entry, self.table_port())

    def with_cogging(self, order: int, amplitude: float, phase: float) -> tuple[ModelDoc, str]:
        """Add a cogging harmonic to the (first) Pmsm; returns the doc and the slot prefix."""
        motors = self.of_type("Pmsm")
        if not motors:
            raise LookupError(f"{self.source}: the model has no Pmsm to carry cogging")
        new = self._copy()
        params = new.component(motors[0])["params"]
        harmonics = params.setdefault("cogging", [])
        harmonics.append(
            {"order": int(order), "amplitude": float(amplitude), "phase": float(phase)}
        )
        return new, f"{motors[0]}.cog{len(harmonics) - 1}_"

    def bus_voltage(self) -> float | None:
        """No-load DC-bus voltage u_0 [V] of the (first) DcBus, None without one."""
        buses = self.of_type("DcBus")
        return float(self.component(buses[0])["params"]["u_0"]) if buses else None

    def torque_constant(self) -> float | None:
        """K_t = 1.5 p psi_pm [N m/A] of the first Pmsm (amplitude-invariant dq)."""
        motors = self.of_type("Pmsm")
        if not motors:
            return None
        params = self.component(motors[0])["params"]
        return 1.5 * float(params["p"]) * float(params["psi_pm"])

    def with_table_component(
        self, base: str, kind: str, params: dict[str, Any]
    ) -> tuple[ModelDoc, str]:
        """The document with a component of type `kind` on the table's node (its single port
        connected there), named `base` or `base2`, ...; returns the document and the name."""
        name = self._free_name(base)
        entry = {"name": name, "type": kind, "params": dict(params)}
        return self.add_component(entry, self.table_port()), name

    def with_constant_force(self, f_0: float) -> tuple[ModelDoc, str]:
        existing = self.of_type("ConstantForce")
        if existing:
            return self.set(f"{existing[0]}.f_0", f_0), f"{existing[0]}.f_0"
        name = self._free_name("constant_force")
        entry = {"name": name, "type": "ConstantForce", "params": {"f_0": float(f_0)}}
        return self.add_component(entry, self.table_port()), f"{name}.f_0"

    def dump(self, path: str | Path, header: list[str]) -> None:
        """Write the model YAML; a drive gain the fit changed keeps the gain the record's
        effort was converted with (the map's), so the written model reproduces the fit."""
        data = self.data
        g = self.gain_slot()
        if g is not None and self.reference_gain is not None and self.get(g) != self.reference_gain:
            data = {**data, ANALYSIS_SECTION: {REFERENCE_GAIN_KEY: self.reference_gain}}
        text = "".join(f"# {line}\n" for line in header)
        text += yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
        Path(path).write_text(text)


@dataclass(frozen=True, kw_only=True, eq=False)
class Drive:
    """What the twin is driven with: the command and the known disturbances, SI, one base."""

    t_s: np.ndarray
    pos_ref_m: np.ndarray
    vel_ref_m_s: np.ndarray
    acc_ref_m_s2: np.ndarray
    effort_add: np.ndarray | None  # known signal added to the controller effort [effort SI]
    force_ext_N: np.ndarray | None  # known external force on the table [N]
    x0_m: float  # measured position at the start
    sensor: str  # motor_encoder or linear_scale
    v0_m_s: float = 0.0  # measured velocity at the start (a record that begins mid-motion)
    trace_mean: bool = False  # each record sample is the mean over its period (a drive trace)


START_FIT_SAMPLES = 7  # samples of the quadratic whose slope at t_0 is the start velocity
START_FIT_S = 0.006  # [s] the longest span of that quadratic
# [m] a start velocity that moves the table less than this over the fit window is a start at
# rest: a record that begins as the axis sets off (a shadow twin's bag) starts exactly at rest
START_TRAVEL_M = 1e-6


def start_velocity(t_s: np.ndarray, x_m: np.ndarray) -> float:
    """Velocity [m/s] at the first sample: the slope at t_0 of a quadratic through the first
    START_FIT_SAMPLES samples (one quantisation step over the window is all it must resolve),
    0 for a record that starts at rest (START_TRAVEL_M)."""
    # over at most START_FIT_S (at least 3 samples): a slow trace's 7 samples span a move
    h = float(t_s[1] - t_s[0]) if len(t_s) > 1 else 1.0
    n = min(START_FIT_SAMPLES, max(3, int(START_FIT_S / h) + 1), len(t_s))
    if n < 3:
        return 0.0
    coef = np.polyfit(t_s[:n] - t_s[0], x_m[:n] - x_m[0], 2)
    v0 = float(coef[1])
    return v0 if abs(v0) * (t_s[n - 1] - t_s[0]) > START_TRAVEL_M else 0.0


def delayed(rows: np.ndarray, t_s: np.ndarray, delay_s: float) -> np.ndarray:
    """Each row as a recorder that stamps it `delay_s` late sees it: y(t - delay), linearly
    interpolated between samples, the first (last) value held outside the record."""
    return np.array([np.interp(t_s - delay_s, t_s, row) for row in np.atleast_2d(rows)])


def window_mean(rows: np.ndarray, dec: int) -> np.ndarray:
    """Every dec-th column of `rows` replaced by the mean of the dec columns ending there (the
    first: itself), as a trace that averages a fast signal over its sample period records it."""
    rows = np.atleast_2d(rows)
    c = np.concatenate((np.zeros((len(rows), 1)), np.cumsum(rows, axis=1)), axis=1)
    ends = np.arange(0, rows.shape[1], dec)
    starts = np.maximum(ends - dec + 1, 0)
    return (c[:, ends + 1] - c[:, starts]) / (ends - starts + 1)


def drive_from_run(run: MeasuredRun) -> Drive:
    h = run.sample_period_s
    if "pos_cmd_m" in run:
        pos = run["pos_cmd_m"]
        vel = run["vel_cmd_m_s"] if "vel_cmd_m_s" in run else np.gradient(pos, h)
    elif "vel_cmd_m_s" in run:
        vel = run["vel_cmd_m_s"]
        # trapezoidal integration from the measured start position
        pos = run["pos_meas_m"][0] + np.concatenate(
            ([0.0], np.cumsum(0.5 * (vel[1:] + vel[:-1]) * h))
        )
    else:
        raise MeasuredDataError(f"{run.source}: no command (pos_cmd_m or vel_cmd_m_s)")
    adds = [n for n in run.disturbance_names if n.startswith("disturbance_effort_add")]
    forces = [n for n in run.disturbance_names if n.startswith("disturbance_force")]
    return Drive(
        t_s=run.t_s,
        pos_ref_m=pos,
        vel_ref_m_s=vel,
        acc_ref_m_s2=np.gradient(vel, h),
        effort_add=sum(run[n] for n in adds) if adds else None,
        force_ext_N=sum(run[n] for n in forces) if forces else None,
        x0_m=float(run["pos_meas_m"][0]),
        sensor=run.position_sensor,
        v0_m_s=start_velocity(run.t_s, run["pos_meas_m"]),
        trace_mean=run.trace_filter == "mean",
    )


@dataclass(eq=False)
class Twin:
    """A compiled model document, ready to simulate parameter sets against a measured run."""

    doc: ModelDoc
    plant: Any
    engine: Any
    controller: Any
    index: dict[str, tuple[int, ...]]
    nominal: np.ndarray
    lead_m: float | None
    pole_pairs: int | None
    effort_name: str
    effort_unit: str
    has_voltage: bool = False  # the controller has a current loop whose u_q is recorded
    _cache: dict = field(default_factory=dict)

    @classmethod
    def compile(cls, doc: ModelDoc, *, smooth_sensors: bool = True, min_substeps: int = 1) -> Twin:
        from feed_twin.control.config import load_controller_config
        from feed_twin.control.layout import build_cascade
        from feed_twin.plant.config import load_plant
        from feed_twin.sim.engine import Engine

        plant = load_plant(doc.data["plant"], source=doc.source)
        cfg = load_controller_config(doc.data["controller"], source=doc.source)
        controller = build_cascade(cfg)
        nominal = plant.nominal_params()
        if smooth_sensors:
            for name in doc.of_type("Encoder"):
                nominal[plant.param_index[f"{name}.step"]] = SMOOTH_SENSOR_STEP
            for name in doc.of_type("LinearScale"):
                nominal[plant.param_index[f"{name}.resolution"]] = SMOOTH_SENSOR_STEP
            # the current ADC likewise: its rounding and noise made the effort, and through the
            # current loop the position, jump between nearby parameter sets
            for name in doc.of_type("CurrentSensor"):
                nominal[plant.param_index[f"{name}.step"]] = SMOOTH_SENSOR_STEP
                nominal[plant.param_index[f"{name}.noise_std"]] = 0.0
        kinds = {e["type"] for e in doc.data["plant"]["components"]}
        has_voltage = "Pmsm" in kinds
        if "Pmsm" in kinds or "DcMotor" in kinds:
            effort_name, unit = "current_q_A", "A"
        else:
            source = doc.of_type("EffortSource")
            domain = doc.component(source[0])["params"].get("domain") if source else None
            effort_name, unit = (
                ("torque_cmd_Nm", "N m") if domain == "rotational" else ("force_cmd_N", "N")
            )
        nsub = max(min_substeps, _substeps(plant, nominal, controller.base_period_s))
        engine = Engine(
            plant,
            base_period_s=controller.base_period_s,
            substeps=nsub,
            controller=controller,
            params=nominal,
            record=_recorded(has_voltage),
        )
        index = {name: (i,) for i, name in enumerate(plant.param_names)}
        for name, members in doc.ties:
            index[name] = tuple(plant.param_index[m] for m in members)
        screws = doc.of_type("BallScrew")
        lead = float(doc.component(screws[0])["params"]["lead"]) if screws else None
        if lead is None:
            lead = getattr(getattr(cfg, "drive", None), "lead_m", None)
        motors = doc.of_type("Pmsm")
        pole_pairs = int(doc.component(motors[0])["params"]["p"]) if motors else None
        return cls(
            doc=doc,
            plant=plant,
            engine=engine,
            controller=controller,
            index=index,
            nominal=nominal,
            lead_m=lead,
            pole_pairs=pole_pairs,
            effort_name=effort_name,
            effort_unit=unit,
            has_voltage=has_voltage,
        )

    @property
    def base_period_s(self) -> float:
        return float(self.controller.base_period_s)

    def _inputs(self, drive: Drive) -> tuple[np.ndarray, np.ndarray | None, int, int]:
        from feed_twin.sim.program import set_nc_reference

        h = self.base_period_s
        period = float((drive.t_s[-1] - drive.t_s[0]) / (len(drive.t_s) - 1))
        dec = round(period / h)
        if dec < 1 or abs(dec * h - period) > 1e-6 * period:
            raise MeasuredDataError(
                f"the record's sample period {period!r} s is not a whole multiple of the "
                f"model's base period {h!r} s"
            )
        n = len(drive.t_s) * dec
        hold = np.repeat  # known inputs are held between record samples
        ref = np.zeros((n, signals.REF_SIZE))
        if dec == 1:
            set_nc_reference(ref, drive.pos_ref_m, drive.vel_ref_m_s, drive.acc_ref_m_s2)
        else:
            # a trace slower than the controller (a 50 Hz machine trace of a 1 kHz NC): the NC's
            # setpoints ran smoothly between the samples, so they are interpolated, not held (a
            # held position would step by v * period, millimetres at machine feeds)
            fine = drive.t_s[0] + h * np.arange(n)
            # a trace's mean over the period ending at its stamp is the value half a period
            # (less one tick) earlier for a signal smooth over the period: the command's own
            # time
            stamps = drive.t_s - (0.5 * (dec - 1) * h if drive.trace_mean else 0.0)
            set_nc_reference(
                ref,
                np.interp(fine, stamps, drive.pos_ref_m),
                np.interp(fine, stamps, drive.vel_ref_m_s),
                np.interp(fine, stamps, drive.acc_ref_m_s2),
            )
        if drive.effort_add is not None:
            gain = self.doc.reference_gain or 1.0
            ref[:, signals.REF_EFFORT_ADD] = hold(drive.effort_add / gain, dec)
        ext = None
        if drive.force_ext_N is not None:
            if not self.plant.ext_names:
                raise MeasuredDataError(
                    f"the record has a known external force but {self.doc.source} has no "
                    "ExternalForce component to apply it"
                )
            ext = np.zeros((n, len(self.plant.ext_names)))
            ext[:, 0] = hold(drive.force_ext_N, dec)
        return ref, ext, n, dec

    def initial_state(self, x0_m: float, p: np.ndarray) -> np.ndarray:
        """Plant state at rest with the table at x0_m [m] for the parameter vector p."""
        table = self.doc.table_port()
        node = self.plant.node_of[table]
        coord = self.plant.coordinates[self.plant.coordinate_of[node]]
        ratio = float(p[self.plant.param_index[f"derived.ratio_n{node}"]])
        return self.plant.initial_state({coord.name: x0_m / ratio})

    def _x0(self, drive: Drive, p: np.ndarray) -> np.ndarray:
        x = self.initial_state(drive.x0_m, p)
        if drive.v0_m_s != 0.0:
            # every coordinate moves with the table (springs relaxed): its speed scales with
            # the table's as its position does, so the position map gives the velocities
            moving = self.initial_state(drive.v0_m_s, p)
            for c in self.plant.coordinates:
                i = self.plant.state_index[c.position_state]
                x[self.plant.state_index[c.velocity_state]] = moving[i]
        return x

    def start_controller(self, drive: Drive, ref: np.ndarray) -> np.ndarray | None:
        """The controller's state at the record's first sample, as if it had been running:
        interpolator at the first setpoint, velocity estimator (its last encoder sample and
        FIR history) at the measured start velocity. None for a record that starts at rest
        (a fresh controller is right there). A PI velocity loop's integrator stays at zero:
        what it held is not in the record."""
        if drive.v0_m_s == 0.0:
            return None
        from feed_twin.control import layout as lay

        cs = self.controller.initial_state()
        cs[lay.S_INITIALISED] = lay.STARTED
        for i in range(3):
            cs[lay.S_NC_PREV_POS + i] = ref[0, signals.REF_POS_M + i]
            cs[lay.S_NC_POS + i] = ref[0, signals.REF_POS_M + i]
        cs[lay.S_NC_TICK] = 0.0
        period = float(self.controller.params[lay.P_VEL_PERIOD])
        cs[lay.S_ENC_POS_PREV] = drive.x0_m - drive.v0_m_s * period
        fir = len(self.controller.state_names) - lay.S_FIR_HIST
        cs[lay.S_FIR_HIST : lay.S_FIR_HIST + fir] = drive.v0_m_s
        cs[lay.S_VEL_EST] = drive.v0_m_s
        return cs

    def simulate(self, drive: Drive, params: np.ndarray) -> SimOutputs:
        """Simulate each row of `params` (full parameter vectors) on the drive's command."""
        from feed_twin.sim.batch import run_batch
        from feed_twin.sim.engine import check_step

        # keyed by the drive itself, which the cache keeps alive: an id() of a drive already
        # collected can come back for the next one and return its stale inputs
        if self._cache.get("drive") is not drive:
            self._cache = {"drive": drive, "inputs": self._inputs(drive)}
        ref, ext, n, dec = self._cache["inputs"]
        P = np.array(params, dtype=float, ndmin=2)
        ok = np.ones(len(P), dtype=bool)
        for i, row in enumerate(P):
            try:
                self.plant.fill_derived(row)
                check_step(self.plant, row, self.engine.h, self.engine.nsub)
            except ValueError:
                ok[i] = False
        rows = np.flatnonzero(ok)
        T = len(drive.t_s)
        x = np.full((len(P), T), np.nan)
        effort = np.full((len(P), T), np.nan)
        u_q = np.full((len(P), T), np.nan) if self.has_voltage else None
        if len(rows):
            x0 = self._x0(drive, P[rows[0]])
            cs0 = self.start_controller(drive, ref)
            res = run_batch(self.engine, P[rows], n, ref=ref, ext=ext, x0=x0, cs0=cs0)
            if drive.trace_mean and dec > 1:
                # the record's trace averages each channel over its sample period
                pos, eff = (window_mean(s, dec) for s in self._measured_signals(res, 1))
                voltage = window_mean(res["out.u_q_ref_V"], dec) if u_q is not None else None
            else:
                pos, eff = self._measured_signals(res, dec)
                voltage = res["out.u_q_ref_V"][:, ::dec] if u_q is not None else None
            x[rows] = pos[:, :T]
            effort[rows] = eff[:, :T]
            if u_q is not None and voltage is not None:
                u_q[rows] = voltage[:, :T]
            ok[rows] = ~res.diverged
        delay = self.doc.get(EFFORT_DELAY_SLOT)
        if delay != 0.0:
            effort = delayed(effort, drive.t_s, delay)
        return SimOutputs(x_m=x, effort=effort, ok=ok, voltage_q=u_q)

    def _measured_signals(self, res: Any, dec: int) -> tuple[np.ndarray, np.ndarray]:
        return self.measured_signals(res, dec)

    def measured_signals(self, res: Any, dec: int) -> tuple[np.ndarray, np.ndarray]:
        """(position as the measurement system reports it [m], drive effort in SI) of an
        engine result `res` (indexable by recorded signal name, rows = sets), every dec-th
        base tick."""
        sel = slice(None, None, dec)
        if "meas.x_scale_m" in res.names and self.doc.of_type("LinearScale"):
            pos = res["meas.x_scale_m"][:, sel]
        else:
            lead = self.controller_lead()
            pos = res["meas.theta_enc_rad"][:, sel] * lead / (2.0 * math.pi)
        if self.effort_name == "current_q_A":
            eff = res["out.i_q_ref_A"][:, sel]
        else:
            gain = self.doc.reference_gain or 1.0
            eff = res["out.effort_cmd"][:, sel] * gain
        return pos, eff

    def controller_lead(self) -> float:
        lead = self.doc.data["controller"].get("drive", {}).get("lead_m")
        if lead is None:
            raise ConfigError(f"{self.doc.source}: controller.drive.lead_m is needed")
        return float(lead)


def _recorded(has_voltage: bool) -> list[str]:
    names = ["meas.theta_enc_rad", "meas.x_scale_m", "out.effort_cmd", "out.i_q_ref_A"]
    return names + (["out.u_q_ref_V"] if has_voltage else [])


def _substeps(plant: Any, p: np.ndarray, h: float) -> int:
    """The fewest RK4 sub-steps the engine accepts for these parameters (1, 2, 4, ... 64)."""
    from feed_twin.sim.engine import check_step

    for nsub in (1, 2, 4, 8, 16, 32, 64):
        try:
            check_step(plant, p, h, nsub)
            return nsub
        except ValueError:
            continue
    raise ConfigError(f"{plant.source}: no sub-step count up to 64 makes RK4 stable")
