"""The engine: an assembled plant and (optionally) the cascade controller in one compiled loop.

    engine = Engine(model, base_period_s=62.5e-6, controller=build_cascade(cfg))
    result = engine.advance(16000, ref=ref)        # or run(...) from a fresh reset
    result["table.s"], result.names, result.as_dict()

State (plant states, controller state, sensor ring, held controller output, tick counter) lives
in arrays on the engine between calls, so `advance` in chunks gives bit-identical results to one
long call (the ROS lockstep node calls it once per message). `feed_twin.sim.batch.run_batch`
advances N parameter sets at once. Inputs per tick: `ref` (n, REF_SIZE) for the controller,
`drive` (n, OUT_SIZE) for open loop (prescribed duties / effort, OUT_ENABLED = 1 to switch the
power stage on), `ext` (n, number of ExternalForce components) [N].
Recorded signals: every state, every plant auxiliary (`<component>.<signal>`, powers
`<component>.power.<name>` [W], stored energies `stored.<component>.<name>` [J], coordinate
accelerations `<body>.a` [m/s^2] or `<body>.alpha` [rad/s^2]), the sensor
samples as the controller saw them (`meas.<MEAS name>`), the controller outputs
(`out.<OUT name>`) and the controller state (`ctrl.<name>`), at every `output_period_s`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from feed_twin.control.layout import STRUCTURE_SLOTS
from feed_twin.core import signals
from feed_twin.plant.assembly import PlantModel
from feed_twin.sim.kernel import RING, load_kernel

_STRUCTURE_INDEX = np.array(STRUCTURE_SLOTS)  # cp's structural slots, as a fancy index
RK4_STABILITY_MARGIN = 2.5  # explicit RK4 is stable for h*|lambda| < 2.78 on the real axis


class DivergenceError(RuntimeError):
    """A state became NaN, infinite or exceeded its runaway limit."""


@dataclass(frozen=True)
class SimResult:
    """Named, decimated signals of a run: `result["table.s"]`, `result.t`, `result.as_dict()`."""

    t: np.ndarray  # sample times [s]
    names: tuple[str, ...]
    data: np.ndarray  # (len(t), len(names))

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[:, self.names.index(name)]
        except ValueError:
            raise KeyError(
                f"signal {name!r}: not recorded; signals: {', '.join(self.names)}"
            ) from None

    def as_dict(self) -> dict[str, np.ndarray]:
        out = {"t": self.t}
        out.update({n: self.data[:, i] for i, n in enumerate(self.names)})
        return out

    @staticmethod
    def concat(parts: Sequence[SimResult]) -> SimResult:
        return SimResult(
            t=np.concatenate([p.t for p in parts]),
            names=parts[0].names,
            data=np.concatenate([p.data for p in parts]),
        )


def _vector(name: str, value: np.ndarray, owner) -> np.ndarray:
    """A parameter vector as the kernel reads it: float64, one value per slot of `owner` (the
    PlantModel's `param_names`, or the compiled controller's)."""
    a = np.array(value, dtype=float)
    if a.shape != (len(owner.param_names),):
        raise ValueError(f"{name}: shape {a.shape} given, expected ({len(owner.param_names)},)")
    return a


def _as_2d(array: np.ndarray, n: int, width: int, what: str) -> np.ndarray:
    a = np.ascontiguousarray(array, dtype=np.float64)
    if a.ndim == 1 and width == 1:
        a = a[:, None]
    if a.shape != (n, width):
        raise ValueError(f"{what}: shape {a.shape} given, expected ({n}, {width})")
    return a


class Engine:
    """Fixed-step simulation of a PlantModel with the controller inside the compiled loop."""

    def __init__(
        self,
        model: PlantModel,
        *,
        base_period_s: float,
        substeps: int = 1,
        output_period_s: float | None = None,
        seed: int = 0,
        controller=None,  # feed_twin.control.layout.CompiledCascade, None for open loop
        params: np.ndarray | None = None,
        record: Sequence[str] | None = None,
        inline_parameters: bool = False,
    ) -> None:
        """`inline_parameters`: compile the plant and controller parameter values into the
        kernel (about 10 % faster per tick; one kernel per parameter set, about 12 s to compile
        and then cached on disk); `p` and `cp` are then fixed for the engine's life, and a
        batch run, whose sets differ, uses the kernel that reads them. Without it the kernel
        reads them, all but the controller's structure (see `kernel_for`)."""
        if not base_period_s > 0.0:
            raise ValueError(f"base_period_s = {base_period_s!r}: must be > 0")
        if substeps < 1:
            raise ValueError(f"substeps = {substeps!r}: must be >= 1")
        self.model = model
        self.h = float(base_period_s)
        self.nsub = int(substeps)
        out_period = self.h if output_period_s is None else output_period_s
        self.dec = round(out_period / self.h)
        if self.dec < 1 or abs(self.dec * self.h - out_period) > 1e-9 * out_period:
            raise ValueError(
                f"output_period_s = {output_period_s!r}: must be an integer multiple of "
                f"base_period_s = {base_period_s!r}"
            )
        self.seed = int(seed)
        self.controller = controller
        if controller is not None and abs(controller.base_period_s - self.h) > 1e-12 * self.h:
            raise ValueError(
                f"base_period_s = {base_period_s!r}: the controller's base period is "
                f"{controller.base_period_s!r}"
            )
        self.inline_parameters = bool(inline_parameters)
        self._p = _vector("params", model.nominal_params() if params is None else params, model)
        check_step(model, self.p, self.h, self.nsub)
        if model.switching_inverter is not None:
            f_pwm = self.p[model.param_index[f"{model.switching_inverter}.f_pwm"]]
            if abs(f_pwm * self.h - 1.0) > 1e-9:
                raise ValueError(
                    f"{model.source}: plant.{model.switching_inverter}.f_pwm = {float(f_pwm)!r}: "
                    f"the switching inverter needs one PWM period per base tick, "
                    f"1/base_period_s = {1.0 / self.h!r} Hz"
                )
        cp = np.array(controller.params, dtype=float) if controller is not None else np.zeros(1)
        self._cp = cp
        self._kernels: dict[tuple[float, ...], ModuleType] = {}  # by controller structure
        self._inlined: ModuleType | None = None
        if self.inline_parameters:
            self._p.flags.writeable = False  # the kernel has the values, not the array
            self._cp.flags.writeable = False
            self._inlined = load_kernel(
                model,
                closed_loop=controller is not None,
                substeps=self.nsub,
                p_slots=self._p.tolist(),
                cp_slots=self._cp.tolist() if controller is not None else None,
            )
        ctrl_names = tuple(controller.state_names) if controller is not None else ()
        self.all_names = (
            model.state_names
            + model.aux_names
            + tuple(f"meas.{n}" for n in signals.MEAS_NAMES)
            + tuple(f"out.{n}" for n in signals.OUT_NAMES)
            + tuple(f"ctrl.{n}" for n in ctrl_names)
        )
        index = {n: i for i, n in enumerate(self.all_names)}
        names = self.all_names if record is None else tuple(record)
        missing = [n for n in names if n not in index]
        if missing:
            raise KeyError(f"record: unknown signal(s) {', '.join(missing)}")
        self.record_names = names
        self.sel = np.array([index[n] for n in names], dtype=np.int64)
        self.n_ext = max(len(model.ext_names), 1)
        self.work = np.zeros(self.kernel.work_size(len(ctrl_names)))
        # no noise drawn ahead: the kernel draws a run's own (run_batch shares tables)
        self._no_normals = np.zeros((0, self.kernel.N_NOISE))
        self._zeros: dict[tuple[int, int], np.ndarray] = {}  # absent inputs (the kernel reads)
        # advance_held's record row, status and zero drive and external inputs
        self._held: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.reset()

    @property
    def p(self) -> np.ndarray:
        """The plant's parameter vector (slots `model.param_names`)."""
        return self._p

    @p.setter
    def p(self, value: np.ndarray) -> None:
        self._settable("p")
        self._p = _vector("p", value, self.model)

    @property
    def cp(self) -> np.ndarray:
        """The controller's parameter vector (`controller.param_names`)."""
        return self._cp

    @cp.setter
    def cp(self, value: np.ndarray) -> None:
        self._settable("cp")
        if self.controller is None:
            raise ValueError("cp: this engine runs open loop, it has no controller parameters")
        self._cp = _vector("cp", value, self.controller)

    def _settable(self, name: str) -> None:
        if self.inline_parameters:
            raise ValueError(
                f"{name}: this engine's parameters are compiled into its kernel "
                "(engine.inline_parameters: true); build another Engine for other values"
            )

    @property
    def kernel(self) -> ModuleType:
        """The compiled loop `advance` runs: the one with this engine's parameter values inlined,
        or else `kernel_for(cp)`."""
        if self._inlined is not None:
            return self._inlined
        return self.kernel_for(self._cp)

    def kernel_for(self, cp: np.ndarray) -> ModuleType:
        """The kernel that reads `p` and `cp`, compiled for the controller structure of `cp`
        (the slots feed_twin.control.layout.STRUCTURE_SLOTS: mode, loops, rates, ...).

        Looked up at every `advance`, so a structure changed in `cp`, even in place, runs on its
        own kernel; a new structure compiles once (about 12 s for axis_default, then cached on
        disk)."""
        if self.controller is None:
            key: tuple[float, ...] = ()
        else:
            key = tuple(cp[_STRUCTURE_INDEX].tolist())
        kernel = self._kernels.get(key)
        if kernel is None:
            cp_slots = None
            if self.controller is not None:
                fixed = dict(zip(STRUCTURE_SLOTS, key, strict=True))
                cp_slots = [fixed.get(i) for i in range(len(cp))]
            kernel = load_kernel(
                self.model,
                closed_loop=self.controller is not None,
                substeps=self.nsub,
                cp_slots=cp_slots,
            )
            self._kernels[key] = kernel
        return kernel

    def reset(
        self,
        x0: np.ndarray | None = None,
        positions: Mapping[str, float] | None = None,
        cs0: np.ndarray | None = None,
    ) -> None:
        """Back to tick 0: plant state x0 (or at rest at `positions`), fresh controller state."""
        self.x = (
            np.array(x0, dtype=float) if x0 is not None else self.model.initial_state(positions)
        )
        if self.controller is not None:
            self.cs = np.array(self.controller.initial_state() if cs0 is None else cs0, float)
        else:
            self.cs = np.zeros(0)
        self.ring = np.zeros((RING, signals.MEAS_SIZE))
        self.out = np.zeros(signals.OUT_SIZE)
        self.k = 0

    def advance(
        self,
        n_ticks: int,
        ref: np.ndarray | None = None,
        drive: np.ndarray | None = None,
        ext: np.ndarray | None = None,
        *,
        hold: int = 1,
        normals: np.ndarray | None = None,
    ) -> SimResult:
        """Advance n_ticks base periods from the current tick; returns what was recorded.

        The inputs have one row per `hold` ticks (the last row may hold for fewer), each held
        over its ticks: NC samples advance with hold = dec and no row repeated per tick.
        `normals`: the sensor noise's standard normal samples of these ticks, drawn ahead
        (`standard_normals` of an engine with the same `noise_key`, which draws the same
        doubles), or None: the loop draws them."""
        if int(hold) != hold or hold < 1:
            raise ValueError(f"hold = {hold!r}: must be an integer >= 1")
        hold = int(hold)
        if normals is None:
            normals = self._no_normals
        elif normals.shape != (n_ticks, self.kernel.N_NOISE):
            raise ValueError(
                f"normals: shape {normals.shape} given, expected ({n_ticks}, {self.kernel.N_NOISE})"
            )
        rows = -(-n_ticks // hold)
        ref2, drive2, ext2 = self.tick_inputs(rows, ref=ref, drive=drive, ext=ext)
        k0 = self.k
        # the recorded ticks: the multiples of dec in [k0, k0 + n_ticks)
        rec_ticks = np.arange(-(-k0 // self.dec) * self.dec, k0 + n_ticks, self.dec)
        rec = np.full((len(rec_ticks), len(self.sel)), np.nan)
        status = np.zeros(4)
        done = self.kernel.advance(
            self.x,
            self.p,
            self.cp,
            self.cs,
            k0,
            n_ticks,
            ref2,
            drive2,
            ext2,
            hold,
            self.seed,
            normals,
            self.ring,
            self.out,
            self.h,
            self.dec,
            self.sel,
            rec,
            self.model.state_limits,
            status,
            self.work,
        )
        self.k = k0 + done
        if status[0] != 0.0:
            raise DivergenceError(divergence_message(self.model, status, self.h))
        return SimResult(t=rec_ticks * self.h, names=self.record_names, data=rec)

    def advance_held(self, ref: np.ndarray) -> np.ndarray:
        """One recorded period (`dec` ticks) from a recorded tick with the reference row `ref`
        (shape (1, REF_SIZE)) held over it, no drive or external input: `advance(dec, ref,
        hold=dec)` without its per-call arrays, for a host that advances one exchange per call
        thousands of times a second (feed_twin.nodeset.drive_host). Returns the one recorded
        row, a view valid until the next call."""
        k0 = self.k
        if k0 % self.dec or ref.shape != (1, signals.REF_SIZE):
            raise ValueError(
                f"advance_held: at tick {k0} with ref of shape {ref.shape}: needs a recorded "
                f"tick (a multiple of {self.dec}) and shape (1, {signals.REF_SIZE})"
            )
        if self._held is None:
            _, drive, ext = self.tick_inputs(1)
            self._held = (np.empty((1, len(self.sel))), np.zeros(4), drive, ext)
        rec, status, drive, ext = self._held
        done = self.kernel.advance(
            self.x, self.p, self.cp, self.cs, k0, self.dec, ref, drive, ext, self.dec, self.seed,
            self._no_normals, self.ring, self.out, self.h, self.dec, self.sel, rec,
            self.model.state_limits, status, self.work,
        )  # fmt: skip
        self.k = k0 + done
        if status[0] != 0.0:
            message = divergence_message(self.model, status, self.h)
            status[:] = 0.0
            raise DivergenceError(message)
        return rec[0]

    @property
    def noise_key(self) -> tuple[int, tuple[int, ...]]:
        """What the sensor noise's samples depend on besides the tick: the seed and the plant's
        channel keys. Engines with equal keys draw the same doubles at the same tick."""
        return self.seed, tuple(self.kernel.NOISE_KEYS)

    def standard_normals(self, n_ticks: int) -> np.ndarray:
        """(n_ticks, channels): the standard normal samples of the next n_ticks ticks, for
        `advance(..., normals=)` of this engine or another with the same `noise_key`."""
        table = np.empty((n_ticks, self.kernel.N_NOISE))
        self.kernel.standard_normals(self.seed, self.k, n_ticks, table)
        return table

    def tick_inputs(
        self,
        n_ticks: int,
        *,
        ref: np.ndarray | None = None,
        drive: np.ndarray | None = None,
        ext: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ref, drive, ext) as the kernel takes them, n_ticks rows (one per tick, or per `hold`
        ticks of `advance`): (n, REF_SIZE), (n, OUT_SIZE), (n, n_ext); zeros for one not given."""
        return (
            self._input(ref, n_ticks, signals.REF_SIZE, "ref"),
            self._input(drive, n_ticks, signals.OUT_SIZE, "drive"),
            self._input(ext, n_ticks, self.n_ext, "ext"),
        )

    def _input(self, array: np.ndarray | None, n: int, width: int, what: str) -> np.ndarray:
        """An input as the kernel takes it; an absent one is zeros, made once per shape (a
        host advancing one exchange at a time calls this thousands of times a second)."""
        if array is not None:
            return _as_2d(array, n, width, what)
        zeros = self._zeros.get((n, width))
        if zeros is None:
            zeros = self._zeros[(n, width)] = np.zeros((n, width))
        return zeros

    def run(self, n_ticks: int, **inputs) -> SimResult:
        """reset() then advance(n_ticks, ...)."""
        self.reset()
        return self.advance(n_ticks, **inputs)


def divergence_message(model: PlantModel, status: np.ndarray, h: float) -> str:
    k, i, value = int(status[1]), int(status[2]), float(status[3])
    state = model.state_names[i]
    coordinate = next(
        (c for c in model.coordinates if state in (c.position_state, c.velocity_state)), None
    )
    if coordinate is not None:
        ports = sorted({p for n in coordinate.nodes for p in model.nodes[n].ports})
        owner = f"coordinate {coordinate.name} (flanges {', '.join(ports)})"
    else:
        owner = f"component {state.split('.')[0]}"
    return (
        f"simulation diverged at t = {(k + 1) * h:.6g} s (tick {k}): state {state} of {owner} "
        f"= {value!r}, limit {float(model.state_limits[i])!r}"
    )


def oscillation_rate(model: PlantModel, p: np.ndarray) -> float:
    """[rad/s] The fastest oscillation a two-port spring makes between the coordinates of its
    ports for the parameter vector p (derived slots filled): omega^2 = k (r_a^2 / M_a +
    r_b^2 / M_b) with each coordinate's inertia M and the port's ratio r to it, the frequency
    of the two inertias on the spring alone (Component.stiffness_bound; an upper bound where
    a coordinate is held by more than this spring's inertias). 0 without springs."""
    fastest = 0.0
    for name, comp in model.components.items():

        def slot(field: str, name: str = name) -> float:
            return float(p[model.param_index[f"{name}.{field}"]])

        k = comp.stiffness_bound(slot)
        if k <= 0.0:
            continue
        ends = [model.node_of[f"{name}.{port}"] for port in ("a", "b")]
        coords = [model.coordinate_of[n] for n in ends]
        if coords[0] == coords[1]:
            continue  # both ends move together: the spring is never stretched
        mobility = 0.0
        for node, c in zip(ends, coords, strict=True):
            r = float(p[model.param_index[f"derived.ratio_n{node}"]])
            inv = float(p[model.param_index[f"derived.inv_inertia.{model.coordinates[c].name}"]])
            mobility += r * r * inv
        fastest = max(fastest, math.sqrt(k * mobility))
    return fastest


def check_step(model: PlantModel, p: np.ndarray, h: float, nsub: int) -> None:
    """Refuse a sub-step for which a regularised friction or damper, or a component's own
    fast states (Component.state_rate), make RK4 unstable."""
    hs = h / nsub
    for name, comp in model.components.items():

        def slot(field: str, name: str = name) -> float:
            return float(p[model.param_index[f"{name}.{field}"]])

        for port, c in comp.damping_bounds(slot).items():
            node = model.node_of[f"{name}.{port}"]
            coord = model.coordinates[model.coordinate_of[node]]
            r = p[model.param_index[f"derived.ratio_n{node}"]]
            inv = p[model.param_index[f"derived.inv_inertia.{coord.name}"]]
            rate = float(hs * c * r * r * inv)
            if rate >= RK4_STABILITY_MARGIN:
                raise ValueError(
                    f"{model.source}: plant.{name}: step {hs:.6g} s times damping slope {c:.6g} "
                    f"over the effective inertia {float(1.0 / (r * r * inv)):.6g} is {rate:.3g}, "
                    f"must be < "
                    f"{RK4_STABILITY_MARGIN} for explicit RK4: raise the regularisation "
                    "velocity or engine.substeps"
                )
        rate = hs * comp.state_rate(slot)
        if rate >= RK4_STABILITY_MARGIN:
            raise ValueError(
                f"{model.source}: plant.{name}: step {hs:.6g} s times its states' fastest "
                f"rate {comp.state_rate(slot):.6g} 1/s is {rate:.3g}, must be < "
                f"{RK4_STABILITY_MARGIN} for explicit RK4: raise engine.substeps"
            )
