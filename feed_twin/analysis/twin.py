"""The workflow's only door to the integrated model: batch simulation of model documents.

`ModelDoc` (feed_twin.analysis.model_doc) holds a model YAML and its edits.
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

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feed_twin.analysis.drive_stage import expanded
from feed_twin.analysis.fit import SimOutputs
from feed_twin.analysis.model_doc import (
    ANALYSIS_SECTION,
    COMMAND_DELAY_SLOT,
    EFFORT_DELAY_SLOT,
    POLE_PAIRS_KEY,
    POSITION_DELAY_SLOT,
    RIPPLE_SLOTS,
    TRACE_WINDOW_SLOT,
    ModelDoc,
)
from feed_twin.analysis.recorder import (
    deaveraged,
    delayed,
    period_mean,
    start_velocity,
)
from feed_twin.core import signals
from feed_twin.core.config import ConfigError
from feed_twin.io.measured import PERIOD_RTOL, MeasuredDataError, MeasuredRun, PlannedCommand

START_SAMPLES = 8  # the first trace samples a start is read off (Twin._started)
SMOOTH_SENSOR_STEP = 1e-12  # [rad or m] sensor step of the fitting twin (see module docstring)
# [s] a record sampled slower than this (a monitoring log) has its command interpolated by a
# smooth cubic between its samples (Twin._inputs); faster traces, linearly (kept as they were)
SLOW_COMMAND_S = 0.02


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
    # the recorded effort is the one that acted up to its stamp (a measured current), not the
    # command issued at it (MeasuredRun.effort_sample)
    effort_actual: bool = True
    # the command at the NC's own period (a program planned for the record): the setpoints
    # are taken from it instead of from the record's samples of pos_ref_m .. acc_ref_m_s2
    plan: PlannedCommand | None = None
    # the measured position's samples: a trace of window means starts the twin from the
    # position and velocity they are the means of (Twin._started)
    x_meas_m: np.ndarray | None = None

    @classmethod
    def at_rest(
        cls,
        t_s: np.ndarray,
        *,
        x0_m: float = 0.0,
        trace_mean: bool = False,
        plan: PlannedCommand | None = None,
    ) -> Drive:
        """A command that holds 0 m on the motor encoder, with no known disturbance: the loop
        settling from `x0_m`, or the command a `plan` carries instead of the samples."""
        zero = np.zeros_like(t_s)
        return cls(
            t_s=t_s,
            pos_ref_m=zero,
            vel_ref_m_s=zero,
            acc_ref_m_s2=zero,
            effort_add=None,
            force_ext_N=None,
            x0_m=x0_m,
            sensor="motor_encoder",
            trace_mean=trace_mean,
            plan=plan,
        )


# a start from a wrong state has settled when what is left of it is below e^-3 = 5 % of its
# largest deviation (three time constants of a first-order loop; Twin.settle_time_s)
SETTLE_LEVEL = math.exp(-3.0)
SETTLE_OFFSET_M = 1e-4  # [m] the start's distance from the setpoint (force >> friction)
SETTLE_HORIZON_S = 2.0  # [s] the longest settling looked for


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
        effort_add=functools.reduce(np.add, [run[n] for n in adds]) if adds else None,
        force_ext_N=functools.reduce(np.add, [run[n] for n in forces]) if forces else None,
        x0_m=float(run["pos_meas_m"][0]),
        sensor=run.position_sensor,
        v0_m_s=start_velocity(run.t_s, run["pos_meas_m"]),
        trace_mean=run.trace_filter == "mean",
        effort_actual=run.effort_sample == "actual",
        plan=run.plan,
        x_meas_m=run["pos_meas_m"],
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
    # the Pmsm an expanded torque-source twin measures its effort on (analysis.drive_stage)
    stage_motor: str | None = None
    # the EffortSource that carries its drive's current loop (plant.current_loop): its effort
    # is the loop's actual current
    loop_source: str | None = None
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
        stage_motor = _stage_motor(doc)
        loop_source = _loop_source(doc)
        if stage_motor is not None:
            # a torque-source twin with its drive's electrical stage (analysis.drive_stage):
            # its effort is still the record's torque, now from the motor's actual current
            effort_name, unit = "torque_cmd_Nm", "N m"
        elif "Pmsm" in kinds or "DcMotor" in kinds or doc.effort_signal() == "current_q_A":
            effort_name, unit = "current_q_A", "A"
        else:
            source = doc.of_type("EffortSource")
            domain = doc.component(source[0])["params"].get("domain") if source else None
            effort_name, unit = (
                ("torque_cmd_Nm", "N m") if domain == "rotational" else ("force_cmd_N", "N")
            )
        # the model's own engine.substeps, when it gives more than stability needs
        given = (doc.data.get("engine") or {}).get("substeps", 1)
        if isinstance(given, bool) or not isinstance(given, int) or given < 1:
            raise ConfigError(
                f"{doc.source}: engine.substeps = {given!r}: must be a whole number >= 1"
            )
        nsub = max(min_substeps, given, substeps_needed(plant, nominal, controller.base_period_s))
        engine = Engine(
            plant,
            base_period_s=controller.base_period_s,
            substeps=nsub,
            controller=controller,
            params=nominal,
            record=_recorded(
                has_voltage, stage_motor or loop_source, "i_q" if stage_motor else "i"
            ),
        )
        index: dict[str, tuple[int, ...]] = {n: (i,) for i, n in enumerate(plant.param_names)}
        for name, members in doc.ties:
            index[name] = tuple(plant.param_index[m] for m in members)
        screws = doc.of_type("BallScrew")
        lead = float(doc.component(screws[0])["params"]["lead"]) if screws else None
        if lead is None:
            lead = getattr(getattr(cfg, "drive", None), "lead_m", None)
        pole_pairs = _pole_pairs(doc)
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
            stage_motor=stage_motor,
            loop_source=loop_source,
        )

    @property
    def base_period_s(self) -> float:
        return float(self.controller.base_period_s)

    @property
    def effort_is_current(self) -> bool:
        """The twin's effort is a current its model integrates (a current loop's source, an
        expanded drive stage's motor): a state, what acted up to its stamp as it stands, where
        a command (the controller's effort or current setpoint) acts from the next tick
        (`acted`)."""
        return self.loop_source is not None or self.stage_motor is not None

    def _cubic_setpoints(self) -> bool:
        """The controller fine-interpolates the NC setpoints by a cubic (`interpolation:
        cubic`)."""
        position = self.controller.config.position
        return position is not None and position.interpolation == "cubic"

    def _inputs(
        self, drive: Drive, window_ticks: int | None = None
    ) -> tuple[np.ndarray, np.ndarray | None, int, int]:
        """(reference rows, external force, base ticks, base ticks per record sample) of the
        drive; `window_ticks`: the trace's window over which its command samples are means
        (default: the map's, a sample period for `trace_filter: mean`, else none)."""
        from feed_twin.sim.program import set_nc_reference

        h = self.base_period_s
        period = float((drive.t_s[-1] - drive.t_s[0]) / (len(drive.t_s) - 1))
        dec = round(period / h)
        if dec < 1 or abs(dec * h - period) > PERIOD_RTOL * period:
            raise MeasuredDataError(
                f"the record's sample period {period:.6g} s is not a whole multiple of the "
                f"model's base period {h:.6g} s (within {PERIOD_RTOL:g} of it)"
            )
        n = len(drive.t_s) * dec
        hold = np.repeat  # known inputs are held between record samples
        ref = np.zeros((n, signals.REF_SIZE))
        if window_ticks is None:
            window_ticks = dec if drive.trace_mean else 1
        if drive.plan is not None:
            # base tick j is at t_0 + j h on the record's clock, where the plan lies: the NC's
            # own setpoints between the record's samples (a stop's final approach too)
            fine = drive.t_s[0] + h * np.arange(n)
            plan = drive.plan
            set_nc_reference(ref, *(np.interp(fine, plan.t_s, y) for y in plan.setpoints))
        elif dec == 1 and window_ticks <= 1:
            set_nc_reference(ref, drive.pos_ref_m, drive.vel_ref_m_s, drive.acc_ref_m_s2)
        else:
            # a trace slower than the controller (a 50 Hz machine trace of a 1 kHz NC): the NC's
            # setpoints ran smoothly between the samples, so they are interpolated, not held (a
            # held position would step by v * period, millimetres at machine feeds)
            fine = drive.t_s[0] + h * np.arange(n)
            if window_ticks > 1:
                # each command sample is a mean over the trace's window: the smooth command
                # whose window means they are (recorder.deaveraged)
                set_nc_reference(ref, *deaveraged(drive.t_s, drive.pos_ref_m, fine, window_ticks))
            elif period > SLOW_COMMAND_S or (
                self._cubic_setpoints() and period > self.controller.config.nc_period_s
            ):
                # a drive that fine-interpolates a cubic through the NC points' positions and
                # velocities needs the two to agree: the linear pieces' velocities are not
                # their positions' slopes, and its cubic wiggled between them (a 20 ms trace's
                # effort came out of phase with the machine's)
                set_nc_reference(ref, *_smooth_command(fine, drive.t_s, drive.pos_ref_m))
            else:
                set_nc_reference(
                    ref,
                    np.interp(fine, drive.t_s, drive.pos_ref_m),
                    np.interp(fine, drive.t_s, drive.vel_ref_m_s),
                    np.interp(fine, drive.t_s, drive.acc_ref_m_s2),
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

    def _loop_started(
        self,
        drive: Drive,
        x0: np.ndarray,
        p: np.ndarray,
        ref: np.ndarray,
        ext: np.ndarray | None,
        cs0: np.ndarray | None,
    ) -> np.ndarray:
        """The start state with the drive's current loop running (plant.current_loop), for a
        record that begins mid-motion: the current at the controller's first setpoint and the
        integral at the voltage that holds it, R i + k_e omega (an ideal source's effort
        starts at that setpoint too: `acted`). At rest, or without a loop, x0 as it is."""
        if self.loop_source is None or drive.v0_m_s == 0.0:
            return x0
        from feed_twin.sim.batch import run_batch

        first = run_batch(
            self.engine,
            p[None, :],
            1,
            ref=ref[:1],
            ext=None if ext is None else ext[:1],
            x0=x0,
            cs0=None if cs0 is None else cs0.copy(),
        )
        i0 = float(first["out.effort_cmd"][0, 0])
        name, index = self.loop_source, self.plant.param_index
        node = self.plant.node_of[f"{name}.flange"]
        coord = self.plant.coordinates[self.plant.coordinate_of[node]]
        omega = (
            x0[self.plant.state_index[coord.velocity_state]] * p[index[f"derived.ratio_n{node}"]]
        )
        k_e = p[index[f"{name}.emf_ratio"]] * p[index[f"{name}.gain"]]
        x = x0.copy()
        x[self.plant.state_index[f"{name}.i"]] = i0
        x[self.plant.state_index[f"{name}.z"]] = p[index[f"{name}.R_s"]] * i0 + k_e * omega
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

    def settle_time_s(self) -> float:
        """[s] How long the nominal closed loop takes to settle from a wrong start state: the
        twin held at a setpoint, started SETTLE_OFFSET_M away from it; the last time its
        effort or position is off its final value by more than SETTLE_LEVEL of the largest
        deviation. Simulated, not derived from one gain: the velocity loop's bandwidth can be
        below the position gain (EMPS: 90 against 160 1/s), and then the slowest pole is a
        lightly damped pair whose decay neither gain gives."""
        h = self.base_period_s
        t = h * np.arange(round(SETTLE_HORIZON_S / h))
        drive = Drive.at_rest(t, x0_m=SETTLE_OFFSET_M)
        out = self.simulate(drive, self.nominal[None, :])
        if not out.ok[0]:
            raise ConfigError(f"{self.doc.source}: the nominal loop diverges from rest")
        last = 0
        for y in (out.x_m[0], out.effort[0] if out.effort is not None else None):
            if y is None:
                continue
            dev = np.abs(y - y[-1])
            if dev.max() > 0.0:
                last = max(last, int(np.flatnonzero(dev > SETTLE_LEVEL * dev.max())[-1]))
        return float(t[last])

    def first_evidence(self, drive: Drive) -> int:
        """Index of the record's first sample that is evidence about the plant's effects.

        Only a trace that averages over its sample period has samples that are not: its first
        sample averages a window before the twin's start, and the twin starts from a state read
        off averaged samples (position off by the travel in half a window, following error
        and held force unknown), so its closed loop settles from a wrong state for
        settle_time_s. A sample whose window starts inside that settling is left out. A raw
        sample is the state itself (up to noise): none is left out.
        """
        h = self.base_period_s
        period = float((drive.t_s[-1] - drive.t_s[0]) / (len(drive.t_s) - 1))
        dec = round(period / h)
        if not drive.trace_mean or dec <= 1:
            return 0
        settle_ticks = self.settle_time_s() / h
        # sample k averages ticks k*dec - dec + 1 .. k*dec; evidence once the first of them
        # is at or after the end of the settling
        return min(len(drive.t_s), math.ceil((settle_ticks + dec - 1) / dec - 1e-9))

    def record_slots(self, drive: Drive) -> dict[str, float]:
        """The record's own slots (model_doc.RECORD_SLOTS) of this model on `drive`: the
        delays, and the trace's window, the map's (a sample period for `trace_filter: mean`,
        else one base tick) unless the model has its own."""
        h = self.base_period_s
        declared = drive_period(drive) if drive.trace_mean else h
        window = self.doc.get(TRACE_WINDOW_SLOT) if self.doc.has_slot(TRACE_WINDOW_SLOT) else None
        return {
            COMMAND_DELAY_SLOT: self.doc.get(COMMAND_DELAY_SLOT),
            EFFORT_DELAY_SLOT: self.doc.get(EFFORT_DELAY_SLOT),
            POSITION_DELAY_SLOT: self.doc.get(POSITION_DELAY_SLOT),
            TRACE_WINDOW_SLOT: declared if window is None else window,
        } | {slot: self.doc.get(slot) for slot in RIPPLE_SLOTS}

    def simulate(
        self,
        drive: Drive,
        params: np.ndarray,
        *,
        effort_delays: Sequence[float] | None = None,
        record: Sequence[Mapping[str, float]] | None = None,
    ) -> SimOutputs:
        """Simulate each row of `params` (full parameter vectors) on the drive's command.

        With `record` (a list of {record slot: value}, model_doc.RECORD_SLOTS) and one row of
        params, the outputs have one row per entry: the signals as a trace with those slots at
        those values records them (one simulation for a search of the record's delays or
        window). `effort_delays`: the same for the effort's delays [s].
        """
        from feed_twin.sim.batch import run_batch
        from feed_twin.sim.engine import check_step

        P = np.array(params, dtype=float, ndmin=2)
        if effort_delays is not None:
            if len(P) != 1:
                raise ValueError(f"effort_delays need one parameter row, not {len(P)}")
            record = [{EFFORT_DELAY_SLOT: d} for d in effort_delays]
        if record is not None and len(P) != 1:
            raise ValueError(f"record values need one parameter row, not {len(P)}")
        base = self.record_slots(drive)
        trace = [base] if record is None else [base | dict(values) for values in record]
        ok = np.ones(len(P), dtype=bool)
        for i, row in enumerate(P):
            try:
                self.plant.fill_derived(row)
                check_step(self.plant, row, self.engine.h, self.engine.nsub)
            except ValueError:
                ok[i] = False
        rows = np.flatnonzero(ok)
        T = len(drive.t_s)
        k = len(trace)  # output rows per parameter row
        x = np.full((len(P) * k, T), np.nan)
        effort = np.full((len(P) * k, T), np.nan)
        u_q = np.full((len(P) * k, T), np.nan) if self.has_voltage else None
        # a recorded command is a mean over the trace's window too: one run per window
        groups: dict[int | None, list[int]] = {}
        for j, slots in enumerate(trace):
            groups.setdefault(self._command_window(drive, slots), []).append(j)
        for window, members in groups.items() if len(rows) else ():
            ref, ext, n, dec = self._cached_inputs(drive, window)
            start = self._started(drive, window)
            x0 = self._x0(start, P[rows[0]])
            cs0 = self.start_controller(start, ref)
            x0 = self._loop_started(start, x0, P[rows[0]], ref, ext, cs0)
            res = run_batch(self.engine, P[rows], n, ref=ref, ext=ext, x0=x0, cs0=cs0)
            pos, eff = self._measured_signals(res, 1)
            if drive.effort_actual and not self.effort_is_current:
                # a command acts from the next tick; a current is the actual at its stamp
                eff = acted(eff)
            volt = res["out.u_q_ref_V"] if u_q is not None else None
            for j in members:
                recorded = self._as_recorded(drive, dec, pos, eff, volt, trace[j])
                x[rows * k + j] = recorded[0][:, :T]
                effort[rows * k + j] = recorded[1][:, :T]
                if u_q is not None and recorded[2] is not None:
                    u_q[rows * k + j] = recorded[2][:, :T]
            ok[rows] &= ~res.diverged
        return SimOutputs(x_m=x, effort=effort, ok=np.repeat(ok, k), voltage_q=u_q)

    def sample_means(self, drive: Drive, params: np.ndarray) -> SimOutputs:
        """Each row of `params` on the drive's command, its position and effort the mean over
        each record sample's period up to it: what a slow record can resolve of a motion that
        changes between its samples (a stick-slip of a few milliseconds), over the same time
        at any base period (recorder.period_mean: twins of one axis at different ticks compare
        like for like). The record's own slots (delays, ripple) are not applied; no voltage."""
        from feed_twin.sim.batch import run_batch

        P = np.array(params, dtype=float, ndmin=2)
        for row in P:
            self.plant.fill_derived(row)
        ref, ext, n, dec = self._cached_inputs(drive, None)
        start = self._started(drive, None)
        x0, cs0 = self._x0(start, P[0]), self.start_controller(start, ref)
        x0 = self._loop_started(start, x0, P[0], ref, ext, cs0)
        res = run_batch(self.engine, P, n, ref=ref, ext=ext, x0=x0, cs0=cs0)
        T = len(drive.t_s)
        pos, eff = (period_mean(y, dec)[:, :T] for y in self._measured_signals(res, 1))
        return SimOutputs(x_m=pos, effort=eff, ok=~res.diverged, voltage_q=None)

    def _command_window(self, drive: Drive, slots: dict[str, float]) -> int | None:
        """The window [base ticks] over which the record's command samples are means, None for
        the map's (a command planned from a program is no trace's: it is not shifted)."""
        h = self.base_period_s
        ticks = max(1, round(slots[TRACE_WINDOW_SLOT] / h))
        declared = round(drive_period(drive) / h) if drive.trace_mean else 1
        return None if drive.plan is not None or ticks == declared else ticks

    def _started(self, drive: Drive, window: int | None) -> Drive:
        """The drive with the twin's start read off a trace of window means: the position and
        velocity at the first stamp of the smooth motion whose means the samples are (the
        first sample is the position half a window earlier: at full speed the twin started
        behind its command and its start transient outlasted Twin.first_evidence)."""
        h = self.base_period_s
        dec = round(drive_period(drive) / h)
        ticks = window if window is not None else (dec if drive.trace_mean else 1)
        if ticks <= 1 or drive.x_meas_m is None or drive.v0_m_s == 0.0:
            return drive
        k = min(len(drive.t_s), START_SAMPLES)
        fine = drive.t_s[0] + h * np.arange(dec * k)
        x, v, _ = deaveraged(drive.t_s[:k], drive.x_meas_m[:k], fine, ticks)
        return dataclasses.replace(drive, x0_m=float(x[0]), v0_m_s=float(v[0]))

    def _cached_inputs(self, drive: Drive, window: int | None):
        """Twin._inputs, kept per drive and window."""
        # keyed by the drive itself, which the cache keeps alive: an id() of a drive already
        # collected can come back for the next one and return its stale inputs
        if self._cache.get("drive") is not drive:
            self._cache = {"drive": drive}
        if window not in self._cache:
            self._cache[window] = self._inputs(drive, window)
        return self._cache[window]

    def _as_recorded(
        self,
        drive: Drive,
        dec: int,
        pos: np.ndarray,
        eff: np.ndarray,
        volt: np.ndarray | None,
        slots: dict[str, float],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(position, effort, q-voltage) on the record's samples from the base ticks' values,
        as the record's trace takes them (`slots`: Twin.record_slots): each the mean over the
        trace's window ending at its sample (recorder.period_mean; one tick: the tick itself),
        the position and the effort stamped their delays [s] late, every output the command's
        delay later (a loop that follows its command d later answers d later: the twin is time
        invariant)."""
        h = self.base_period_s
        ticks = max(1, round(slots[TRACE_WINDOW_SLOT] / h))
        common = slots[COMMAND_DELAY_SLOT]
        signals = [pos, self._with_ripple(pos, eff, slots)]
        delays = [slots[POSITION_DELAY_SLOT] + common, slots[EFFORT_DELAY_SLOT] + common]
        if volt is not None:
            signals.append(volt)
            delays.append(common)
        fine = dec > 1 or ticks > 1
        if fine:
            # on the base ticks: a trace's samples are too far apart to shift a transient by
            # a few milliseconds, and a delay commutes with the trace's mean
            fine_t = h * np.arange(pos.shape[1])
            signals = [_shifted(y, fine_t, d) for y, d in zip(signals, delays, strict=True)]
        if ticks > 1:
            signals = [period_mean(y, dec, ticks) for y in signals]
        else:
            signals = [y[:, ::dec] for y in signals]
        if not fine:
            signals = [_shifted(y, drive.t_s, d) for y, d in zip(signals, delays, strict=True)]
        return signals[0], signals[1], signals[2] if volt is not None else None

    def _with_ripple(self, pos: np.ndarray, eff: np.ndarray, slots: dict[str, float]):
        """The effort with the ripple of the record's current-sensor offsets (RIPPLE_SLOTS: sin
        and cos of the electrical angle p 2 pi x / lead of the measured position)."""
        s, c = (slots[k] for k in RIPPLE_SLOTS)
        if s == 0.0 and c == 0.0:
            return eff
        if self.pole_pairs is None or self.lead_m is None:
            raise ConfigError(
                f"{self.doc.source}: a current-offset ripple needs the motor's pole pairs "
                f"({ANALYSIS_SECTION}.{POLE_PAIRS_KEY}) and the screw's lead"
            )
        theta = self.pole_pairs * 2.0 * math.pi * pos / self.lead_m
        return eff + s * np.sin(theta) + c * np.cos(theta)

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
        if self.stage_motor is not None:
            # the drive's actual q-current (its sensor is exact), in the record's torque
            eff = res[f"{self.stage_motor}.i_q"][:, sel] * (self.doc.reference_gain or 1.0)
        elif self.loop_source is not None:
            # the current loop's actual current, in the record's effort
            eff = res[f"{self.loop_source}.i"][:, sel] * (self.doc.reference_gain or 1.0)
        elif self.effort_name == "current_q_A":
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


def _smooth_command(
    fine: np.ndarray, stamps: np.ndarray, pos_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, velocity, acceleration) of a slow record's command between its samples: a
    shape-preserving cubic (PCHIP) through the positions and its derivatives. Linear pieces
    100 ms long turn the velocity into steps at every sample, where the twin's effort is read:
    the loop's answer to each step, not the machine's, would be compared."""
    from scipy.interpolate import PchipInterpolator

    inside = np.clip(fine, stamps[0], stamps[-1])  # held before the first and after the last
    curve = PchipInterpolator(stamps, pos_m)
    held = (fine < stamps[0]) | (fine > stamps[-1])
    vel, acc = curve(inside, 1), curve(inside, 2)
    vel[held] = 0.0
    acc[held] = 0.0
    return curve(inside), vel, acc


def _pole_pairs(doc: ModelDoc) -> int | None:
    """The motor's pole pairs: its Pmsm's, else the model's analysis.pole_pairs (a twin that
    models the drive as an effort source), else unknown."""
    motors = doc.of_type("Pmsm")
    if motors:
        return int(doc.component(motors[0])["params"]["p"])
    given = (doc.data.get(ANALYSIS_SECTION) or {}).get(POLE_PAIRS_KEY)
    if given is None:
        return None
    if isinstance(given, bool) or not isinstance(given, int) or given < 1:
        raise ConfigError(
            f"{doc.source}: {ANALYSIS_SECTION}.{POLE_PAIRS_KEY} = {given!r}: must be a whole "
            "number >= 1"
        )
    return given


def _shifted(y: np.ndarray, t_s: np.ndarray, delay: float) -> np.ndarray:
    return y if delay == 0.0 else delayed(y, t_s, delay)


def acted(effort: np.ndarray, before: np.ndarray | None = None) -> np.ndarray:
    """The effort that acted up to each base tick, from the commands issued at each tick
    (rows = sets): the controller's command of tick k drives the plant over (k, k + 1], so a
    drive's actual current (force) sampled at tick k, before that command takes effect, is the
    command of tick k - 1. At the first tick, `before` (one column: the command of the tick
    before, for a run continued in pieces) or, at a run's start, the first command (the loop
    held it at rest)."""
    out = np.empty_like(effort)
    out[:, 1:] = effort[:, :-1]
    out[:, :1] = effort[:, :1] if before is None else before
    return out


def drive_period(drive: Drive) -> float:
    """[s] The record's sample period."""
    return float((drive.t_s[-1] - drive.t_s[0]) / (len(drive.t_s) - 1))


def _recorded(has_voltage: bool, current_of: str | None = None, state: str = "i_q") -> list[str]:
    """The signals a twin records; `current_of`: the component whose current `state` is the
    effort (an expanded model's motor, a current loop's source)."""
    names = ["meas.theta_enc_rad", "meas.x_scale_m", "out.effort_cmd", "out.i_q_ref_A"]
    names += [f"{current_of}.{state}"] if current_of is not None else []
    return names + (["out.u_q_ref_V"] if has_voltage else [])


def _loop_source(doc: ModelDoc) -> str | None:
    """The EffortSource that carries its drive's current loop, None for any other model."""
    for name in doc.of_type("EffortSource"):
        if doc.component(name)["params"].get("R_s") is not None:
            return name
    return None


def _stage_motor(doc: ModelDoc) -> str | None:
    """The Pmsm of a torque-source twin given its drive's electrical stage
    (analysis.drive_stage.expand), None for any other model."""
    return doc.of_type("Pmsm")[0] if expanded(doc) else None


def substeps_needed(plant: Any, p: np.ndarray, h: float) -> int:
    """The fewest RK4 sub-steps (1, 2, 4, ... 64) the engine accepts for these parameters
    (the damping slopes, engine.check_step) and that keep RK4 stable on the fastest spring's
    oscillation (engine.oscillation_rate: h / nsub * omega < RK4_STABILITY_MARGIN)."""
    from feed_twin.sim.engine import RK4_STABILITY_MARGIN, check_step, oscillation_rate

    omega = oscillation_rate(plant, p)
    for nsub in (1, 2, 4, 8, 16, 32, 64):
        if h / nsub * omega >= RK4_STABILITY_MARGIN:
            continue
        try:
            check_step(plant, p, h, nsub)
            return nsub
        except ValueError:
            continue
    raise ConfigError(f"{plant.source}: no sub-step count up to 64 makes RK4 stable")
