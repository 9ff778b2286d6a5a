"""The component contract: typed ports, parameter slots, owned states and emitted glue.

A component is a frozen, keyword-only parameter dataclass with pure numba equations in its own
module. It never integrates anything itself: the assembler (`feed_twin.plant.assembly`) owns the
state vector, maps each port to a node, and asks every component to `emit` the few lines of glue
that call its equations with the right node variables and parameter slots. The generated lines
are the only place where components meet, so the physics exists once, as numba functions, and
both the compiled kernel and its un-jitted `py_func` (the reference integration) run it.

Component equations (and the controller's laws in feed_twin.control) are compiled without
numba's on-disk cache (`@njit(error_model="numpy", forceinline=True)`, no `cache=True`): numba
caches a function as machine code only, and a kernel compiled later can then call it but LLVM
cannot inline it. Compiled in the kernel's own process, their LLVM IR is linked into the kernel;
`forceinline` marks them alwaysinline for LLVM, which then inlines the few its cost model would
leave as calls, at no compile time (numba's own `inline="always"` would multiply it). The kernel
itself is cached, with them inside
(tests/test_sim_perf.py::test_the_laws_the_kernel_calls_are_not_disk_cached; the measurements:
docs/performance.md).
Small helpers that must vanish into their callers (smooth_sign, sincos, exp_neg) are
`inline="always"`.

Port kinds and their variables (SI):
- `rotational`: across angle phi [rad] and speed omega [rad/s]; through torque tau [N m],
  positive into the flange.
- `translational`: across position s [m] and velocity v [m/s]; through force f [N] into the flange.
- `dc`: bus voltage u [V] (written by the source) and current i [A] drawn by the load.
- `ac3`: three phase voltages u_a, u_b, u_c [V] (pole voltages written by the inverter) and the
  phase currents i_a, i_b, i_c [A] (written by the machine).

Evaluation stages, in order, inside one derivative call: `currents` (machines expose phase
currents from their states), `dc_current` (inverters sum the bus current), `dc_voltage` (the bus
sets its voltage), `voltages` (inverters set the pole voltages), `dynamics` (machines and force
elements compute derivatives and apply through variables), `transmit` (transformers scale the
forces of their output node). `sense` runs only when the sensors are sampled.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Protocol

from feed_twin.plant.effect_api import Effect

PortKind = Literal["rotational", "translational", "dc", "ac3"]
SlotReader = Callable[[str], float]  # parameter slot name of the component -> its value
STAGES = ("currents", "dc_current", "dc_voltage", "voltages", "dynamics", "transmit", "sense")
NAME_PATTERN = re.compile(r"^[a-z][a-z0-9_]*$")


class AssemblyError(ValueError):
    """The components and connections do not form a valid plant."""


@dataclass(frozen=True, kw_only=True)
class StateSpec:
    """One state a component owns (not the mechanical coordinates, which the assembler owns)."""

    name: str  # short name, the full state name is "<component>.<name>"
    unit: str
    limit: float  # |value| above this is a runaway: the engine stops with a divergence error


@dataclass(frozen=True, kw_only=True)
class InertiaSpec:
    """An inertia (or mass) a component puts on one of its mechanical ports."""

    port: str
    slot: str  # parameter slot holding the value [kg m^2] or [kg]
    factor: float = 1.0  # share of the slot value at this port (a shaft puts half at each end)


@dataclass(frozen=True, kw_only=True)
class Quantity:
    """A quantity made of several YAML parameters of a component, read and set as one number by
    the workflow's model document (a screw's axial rigidity EA = E pi d_root^2 / 4: the fit
    identifies EA, the root diameter stays). Declared by the component, so the document itself
    knows no physics."""

    stored_as: tuple[str, ...]  # the parameters it is made of (all present, or it is absent)
    read: Callable[[Mapping[str, Any]], float]
    write: Callable[[dict[str, Any], float], None]  # sets the parameters from the value
    # whether the parameters hold it, where that is more than having them (an indexed entry)
    exists: Callable[[Mapping[str, Any]], bool] | None = None

    def present(self, params: Mapping[str, Any]) -> bool:
        if self.exists is not None:
            return self.exists(params)
        return all(name in params for name in self.stored_as)


@dataclass(frozen=True, kw_only=True)
class SlotSpec:
    """Unit and physical range of a parameter slot computed from several fields (a shaft's
    torsional stiffness from G, d_root and length), which no field comment or range check
    states. A slot that is a field takes both from the field (feed_twin.plant.slot_specs)."""

    unit: str  # "1" for a pure number
    low: float = -math.inf  # smallest value allowed
    low_open: bool = False  # the value must exceed `low`, not reach it
    high: float = math.inf
    high_open: bool = False  # the value must stay below `high`
    integer: bool = False


@dataclass(frozen=True, kw_only=True)
class Component:
    """Base of every plant component; subclasses are frozen keyword-only dataclasses.

    Subclasses set `TYPE` (the YAML `type:`), `PORTS` (port name -> kind) and override what they
    need: `slots()` (parameter slot name -> value, default every float field), `states()`,
    `inertias()` and `emit()` (what changes the generated code needs no declaration: the kernel
    is keyed by the generated source's digest). For
    the discrepancy workflow they declare the effects they can carry (`EFFECTS`, see
    feed_twin.plant.effect_api) and the quantities made of several of their parameters
    (`QUANTITIES`, or `quantity()` for a family of slots).
    """

    TYPE: ClassVar[str]
    PORTS: ClassVar[dict[str, PortKind]]
    EFFECTS: ClassVar[tuple[Effect, ...]] = ()  # effects the workflow may add with it
    QUANTITIES: ClassVar[dict[str, Quantity]] = {}  # slots made of several parameters
    COMPUTED_SLOTS: ClassVar[Mapping[str, SlotSpec]] = {}  # slots() entries that are no field

    @classmethod
    def computed_slot(cls, name: str) -> SlotSpec | None:
        """Unit and range of the computed slot `name` (None: not a computed slot)."""
        return cls.COMPUTED_SLOTS.get(name)

    @classmethod
    def quantity(cls, name: str) -> Quantity | None:
        """The quantity `name` (a slot that is no single YAML parameter), None if undeclared."""
        return cls.QUANTITIES.get(name)

    @classmethod
    def whole_number(cls, name: str) -> bool:
        """True for a field declared `int` (a count, pole pairs): set slot by slot, it stays a
        whole number, while a float field configured as `0` in YAML (a delay in ticks, which
        may be a fraction) stays a float."""
        fields = {f.name: f.type for f in dataclasses.fields(cls)}
        return fields.get(name) in (int, "int")

    # (rotational port, translational port, ratio slot) of an ideal transformer, whose nodes the
    # assembler merges into one coordinate: across(trans) = p[ratio] * across(rot)
    TRANSFORMER: ClassVar[tuple[str, str, str] | None] = None
    HAS_INPUT: ClassVar[bool] = False  # takes an external input channel (a force [N])

    @property
    def lossy(self) -> bool:
        """A transformer with an efficiency below 1 (the force it passes depends on direction)."""
        return False

    @property
    def switching(self) -> bool:
        """An inverter whose legs switch (PWM edges resolved by the loop), not averaged."""
        return False

    # what the component's outputs stand for in an axis's reported state (AxisState field ->
    # own output, "-" for the opposite sign), so reporting never depends on instance names
    STATE_OUTPUTS: ClassVar[Mapping[str, str]] = {}

    def ports(self) -> dict[str, PortKind]:
        return self.PORTS

    def slots(self) -> dict[str, float]:
        values: dict[str, float] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float):
                values[f.name] = value
            elif isinstance(value, int) and not isinstance(value, bool):
                values[f.name] = float(value)
        return values

    def states(self) -> tuple[StateSpec, ...]:
        return ()

    def inertias(self) -> tuple[InertiaSpec, ...]:
        return ()

    def damping_bounds(self, slot: SlotReader) -> dict[str, float]:
        """Largest velocity gradient of a through variable at each port [N s/m or N m s/rad],
        from the parameter values `slot(name)` of the set being run.

        The engine checks h * c / M_eff < 2.5 (explicit RK4 is stable for real eigenvalues down
        to -2.78/h), so a regularised friction that is too sharp for the step is refused.
        """
        del slot
        return {}

    def state_rate(self, slot: SlotReader) -> float:
        """[1/s] The largest pole magnitude of the component's own states' linear dynamics
        (a drive's current loop), from the parameter values `slot(name)` of the set being run;
        0 for none. The engine checks h * rate < 2.5 (explicit RK4 is stable inside |h s| <
        2.5 in every direction of the left half-plane)."""
        del slot
        return 0.0

    def stiffness_bound(self, slot: SlotReader) -> float:
        """Largest stiffness between ports a and b [N/m or N m/rad] of a two-port spring, from
        the parameter values `slot(name)` of the set being run; 0 for none.

        The twin chooses its RK4 sub-steps so that h * omega < RK4_STABILITY_MARGIN for the
        oscillation omega^2 = k (1/M_a + 1/M_b) this spring makes between its two coordinates
        (explicit RK4 is stable on the imaginary axis for h |lambda| < 2.83).
        """
        del slot
        return 0.0

    def emit(self, stage: str, g: Emitter) -> None:
        """Write this component's glue for `stage` through the emitter `g`."""
        del stage, g


class Emitter(Protocol):
    """What a component sees while the assembler generates code (plant.codegen.Generator).

    Every method returns a Python expression or records a line; names are resolved to named
    constants of the generated module, so the generated source reads like hand-written glue.
    """

    def p(self, slot: str) -> str:  # parameter slot of the emitting component
        ...

    def x(self, state: str) -> str:  # own state value
        ...

    def d(self, state: str, expr: str) -> None:  # own state derivative
        ...

    def local(self, name: str) -> str:  # a local variable private to the component
        ...

    def line(self, code: str) -> None: ...

    def call(self, targets: tuple[str, ...], func: str, args: tuple[str, ...]) -> None:
        """`targets = func(args)` where func is a numba function imported by its dotted path."""
        ...

    def across(self, port: str) -> tuple[str, str]:  # (position, velocity) of a mechanical port
        ...

    def apply(self, port: str, expr: str) -> None:  # add a through force/torque at a port
        ...

    def node_force(self, port: str) -> str:  # sum of forces other elements apply at the node
        ...

    def scale_node(self, port: str, expr: str) -> None:  # multiply that sum before it is applied
        ...

    def el(self, port: str, var: str) -> str:  # variable of an electrical node, e.g. ("ac", "i_a")
        ...

    def drive(self, slot: str) -> str:  # controller output OUT_* held over the tick
        ...

    def switch(self, phase: int) -> str:  # switching inverter: state 0/1 of a phase leg
        ...

    def ext(self) -> str:  # this component's external input channel (a force [N])
        ...

    def aux(self, name: str, expr: str) -> None:  # a named auxiliary output
        ...

    def power(self, kind: Literal["source", "loss"], name: str, expr: str) -> None:
        """Power [W] into the system from outside ("source") or dissipated ("loss")."""
        ...

    def stored(self, name: str, expr: str) -> None:  # stored energy [J] (springs, fields, gravity)
        ...

    def meas(self, slot: str, expr: str, delay: str = "0") -> None:  # MEAS_* sample, its delay
        ...

    def noise(self, channel: int, scale: str) -> str:
        """`scale` times a standard normal sample, seeded, per tick and channel (0 when the
        scale is 0, without drawing)."""
        ...

    def angle(self, expr: str) -> tuple[str, str]:
        """(cos, sin) of an angle [rad] made of states, across variables and parameters only
        (a machine's electrical rotor angle, for its Park transform): the emitting component's
        locals `cos` and `sin`, so later stages name them with `local`. One per component.

        The compiled loop evaluates the pair once per tick, at the tick's start state; each
        derivative call inside the tick rotates it by the angle's increment since
        (`feed_twin.core.trig.sincos_near`, a quarter of the work of a sine and a cosine).
        """
        ...


def check_name(name: str) -> None:
    if not NAME_PATTERN.match(name):
        raise ValueError(
            f"name = {name!r}: must start with a lower-case letter and contain only a-z, 0-9, _"
        )
