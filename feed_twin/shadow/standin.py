"""A stand-in for a real axis: a truth model that answers NC commands with measured samples.

The truth is the nominal model document with hidden effects and unmodelled dynamics, built by
the discrepancy workflow's synthetic-data generator (feed_twin.analysis.synthetic.truth_model:
the same components the workflow would add, a current-loop lag, the encoder's real count) and
run on the same engine, one NC period at a time, state kept between calls. The recorded effort
is the command the truth's controller issues at the sample (EFFORT_SAMPLE: a setpoint trace,
as its column map says) with white noise as a real current measurement has. `set_parameter`
changes a parameter of the running truth (e.g. raises the Coulomb friction to play a worn
screw); the change acts from the next call on.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from feed_twin.analysis.synthetic import PROGRAM, Unmodelled, command, truth_model
from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.io import msg_types
from feed_twin.io.bag import QosProfile
from feed_twin.nodeset.roles import node_role
from feed_twin.shadow.config import StandInConfig
from feed_twin.shadow.twin import _Rows
from feed_twin.sim.program import nc_reference

# what the stand-in's effort holds at a stamp (ColumnMap.effort_sample): the command issued at it
EFFORT_SAMPLE = "setpoint"


def program_command(
    duration_s: float, period_s: float, program: str = PROGRAM
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, x, v, a) of a G-code program repeated back to back for `duration_s`, NC samples.

    The program must end where it starts (the default one returns to X0), so repeats join
    without a jump. Velocity and acceleration are the NC's feed-forward signals (central
    differences of the planned position).
    """
    t1, x1 = command(program)
    if abs(x1[-1] - x1[0]) > 1e-9:
        raise ValueError(
            f"program_command: the program ends at {x1[-1]!r} m, not at its start {x1[0]!r} m"
        )
    n = round(duration_s / period_s)
    x = np.resize(x1[:-1], n)
    v = np.gradient(x, period_s)
    a = np.gradient(v, period_s)
    return np.arange(n) * period_s, x, v, a


class StandIn:
    """A truth model driven by NC samples (position, velocity, acceleration feed-forward)."""

    def __init__(
        self,
        nominal: ModelDoc,
        *,
        hidden: Mapping[str, Mapping[str, float]],
        unmodelled: Unmodelled,
        sample_period_s: float,
        x0_m: float,
    ) -> None:
        self.doc = truth_model(nominal, hidden, unmodelled)
        h = float(self.doc.data["controller"]["base_period_s"])
        lag = unmodelled.current_lag_s
        # the lag adds a fast pole: sub-steps keep explicit RK4 well inside its stability limit
        nsub = max(1, int(np.ceil(2.0 * h / lag))) if lag > 0 else 1
        self.twin = Twin.compile(self.doc, smooth_sensors=False, min_substeps=nsub)
        self.engine = self.twin.engine
        self.dec = round(sample_period_s / self.engine.h)
        if self.dec < 1 or abs(self.dec * self.engine.h - sample_period_s) > 1e-9:
            raise ValueError(
                f"sample_period_s = {sample_period_s!r}: must be a whole multiple of the truth "
                f"model's base period {self.engine.h!r} s"
            )
        noise = getattr(unmodelled, "effort_noise_std", None)
        # the synthetic generator's default: 0.3 N on a force, 0.01 A on a measured current
        self.noise_std = (
            noise if noise is not None else (0.01 if self.twin.effort_unit == "A" else 0.3)
        )
        self._rng = np.random.default_rng(unmodelled.seed)
        self.reset(x0_m)

    @classmethod
    def from_config(
        cls, nominal: ModelDoc, config: StandInConfig, *, sample_period_s: float, x0_m: float
    ) -> StandIn:
        """The stand-in the `shadow.standin` section describes (hidden effects, unmodelled)."""
        return cls(
            nominal,
            hidden=config.hidden,
            unmodelled=config.unmodelled(),
            sample_period_s=sample_period_s,
            x0_m=x0_m,
        )

    def reset(self, x0_m: float) -> None:
        """At rest with the table at x0_m [m] (the truth's parameters stay as they are)."""
        self.engine.reset(x0=self.twin.initial_state(x0_m, self.engine.p))

    def step(
        self, x_m: np.ndarray, v_m_s: np.ndarray, a_m_s2: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Measured position [m] and effort [effort unit] at each of the given NC samples."""
        n = len(x_m)
        ref = nc_reference(x_m, v_m_s, a_m_s2, self.dec)
        res = self.engine.advance(n * self.dec, ref=ref)
        x, effort = self.twin.measured_signals(_Rows(res), self.dec)
        return x[0], effort[0] + self._rng.normal(0.0, self.noise_std, n)

    def friction_parameters(self) -> tuple[str, ...]:
        """The Coulomb-friction parameters of the truth (both directions)."""
        friction = self.doc.friction()
        return () if friction is None else (f"{friction}.F_c_pos", f"{friction}.F_c_neg")

    def parameter(self, name: str) -> float:
        return float(self.engine.p[self.twin.plant.param_index[name]])

    def set_parameter(self, name: str, value: float) -> None:
        """Change one truth parameter (e.g. "friction.F_c_pos") from the next step on."""
        index = self.twin.plant.param_index
        if name not in index:
            raise KeyError(f"the stand-in's truth model has no parameter {name!r}")
        p = self.engine.p.copy()
        p[index[name]] = float(value)
        self.twin.plant.fill_derived(p)
        self.engine.p = p


BAG_MAP = """\
# column map of a machine's command and joint_states topics (feed_twin.shadow.standin.write_map)
time: {{column: "{command}:header.stamp", unit: s}}
position_sensor: {sensor}
signals:
  pos_cmd_m: {{column: "{command}:position", unit: m}}
  vel_cmd_m_s: {{column: "{command}:velocity", unit: m/s}}
  pos_meas_m: {{column: "{joints}:position[0]", unit: m}}
{effort_line}plausibility: {{travel_m: {travel!r}, max_speed_m_s: {speed!r}}}
effort_sample: {effort_sample}
"""
EFFORT_LINE = """  {effort}: {{column: "{joints}:effort[0]", unit: {unit}}}
"""
_UNIT_OF = {"force_cmd_N": "N", "torque_cmd_Nm": "Nm", "current_q_A": "A"}


def _feedback_sensor(doc: ModelDoc) -> str:
    """The sensor whose reading the stand-in publishes (Twin.measured_signals' choice)."""
    return "linear_scale" if doc.of_type("LinearScale") else "motor_encoder"


def record_bag(
    path: str | Path,
    standin: StandIn,
    *,
    duration_s: float,
    period_s: float,
    namespace: str = "/cnc/x",
    changes: Sequence[tuple[float, str, float]] = (),
    travel_m: float = 0.3,
    qos: Mapping[str, Sequence[QosProfile]] | None = None,
) -> Path:
    """Run the stand-in on the repeated program and record it as a machine would publish it:
    AxisCommand on `<namespace>/command`, sensor_msgs/JointState (position [m], effort in the
    model's effort unit) on `<namespace>/joint_states`, log time = stamp. `changes` are
    (time [s], parameter, value) applied to the truth during the run; `qos` the offered QoS
    recorded for "command" and "joint_states" (rosbag2's default otherwise). Writes the column map
    `<bag name>_map.yaml` next to the bag and returns its path."""
    from feed_twin.io.bag import BagWriter
    from feed_twin.io.cdr import FlatCodec
    from feed_twin.shadow.bagstreams import encode_joint_state

    path = Path(path)
    t, x, v, a = program_command(duration_s, period_s)
    standin_role = node_role("standin")
    command_topic = standin_role.topic(namespace, "command")
    joints_topic = standin_role.topic(namespace, "joint_states")
    codec = FlatCodec(msg_types.AXIS_COMMAND)
    pending = sorted(changes)
    chunk = max(1, round(0.1 / period_s))
    with BagWriter(path, flush_period_s=None) as writer:
        offered = {} if qos is None else {k: tuple(v) for k, v in qos.items()}
        unknown = sorted(set(offered) - {"command", "joint_states"})
        if unknown:
            raise ValueError(f"qos: unknown topic(s) {unknown}; use 'command', 'joint_states'")
        default = (QosProfile(),)
        writer.add_topic(command_topic, msg_types.AXIS_COMMAND, qos=offered.get("command", default))
        writer.add_topic(
            joints_topic, msg_types.JOINT_STATE, qos=offered.get("joint_states", default)
        )
        for k0 in range(0, len(t), chunk):
            while pending and pending[0][0] <= t[k0]:
                _, name, value = pending.pop(0)
                standin.set_parameter(name, value)
            sl = slice(k0, k0 + chunk)
            xm, em = standin.step(x[sl], v[sl], a[sl])
            for j in range(len(xm)):
                k = k0 + j
                stamp = round(float(t[k]) * 1e9)
                sec, nsec = divmod(stamp, 1_000_000_000)
                writer.write(
                    command_topic,
                    codec.encode_map(
                        {
                            "header.stamp.sec": sec,
                            "header.stamp.nanosec": nsec,
                            "axis": "x",
                            "position": float(x[k]),
                            "velocity": float(v[k]),
                            "acceleration": float(a[k]),
                            "line": -1,
                        }
                    ),
                    log_time_ns=stamp,
                )
                writer.write(
                    joints_topic,
                    encode_joint_state(stamp, ["x"], [float(xm[j])], [], [float(em[j])]),
                    log_time_ns=stamp,
                )
    return write_map(path.with_name(f"{path.name}_map.yaml"), standin.twin, namespace, travel_m)


def write_map(
    path: str | Path,
    twin: Twin,
    namespace: str,
    travel_m: float = 0.3,
    *,
    with_effort: bool = True,
    max_speed_m_s: float = 0.5,
) -> Path:
    """The column map of the stand-in's topics (command and joint_states under `namespace`)
    for a model `twin` (the stand-in's truth or the nominal twin: the same effort signal);
    `with_effort=False` for a machine that reports no effort (LinuxCNC's HAL servo)."""
    path = Path(path)
    joints = node_role("standin").topic(namespace, "joint_states")
    effort = twin.effort_name
    effort_line = EFFORT_LINE.format(effort=effort, joints=joints, unit=_UNIT_OF[effort])
    path.write_text(
        BAG_MAP.format(
            command=node_role("standin").topic(namespace, "command"),
            joints=joints,
            sensor=_feedback_sensor(twin.doc),
            effort_line=effort_line if with_effort else "",
            travel=travel_m,
            speed=max_speed_m_s,
            effort_sample=EFFORT_SAMPLE,
        )
    )
    return path
