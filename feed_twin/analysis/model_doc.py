"""Model documents: a model YAML held as data, with the edits the effect library needs.

`ModelDoc` holds the `plant:` and `controller:` sections of feed_twin.plant.config and
feed_twin.control.cascade as data: set a parameter, tie two slots to one fitted value, add a
component, write the augmented file. Edits return new documents; the nominal file is never
touched. It knows no physics: a slot that is not a YAML parameter but a quantity made of
several (a screw's axial rigidity EA, an averaged inverter's dead fraction, a PMSM's torque
constant, a cogging harmonic's amplitude) is read and set through the `Quantity` its component
declares (feed_twin.plant.component.Component.quantity). It implements the
feed_twin.plant.effect_api.Document protocol the components' effect edits work on.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from feed_twin.core.config import ConfigError, load_yaml
from feed_twin.plant.ball_screw import BallScrew
from feed_twin.plant.component import Quantity
from feed_twin.plant.dc_bus import DcBus
from feed_twin.plant.dc_motor import DcMotor
from feed_twin.plant.effect_api import Document
from feed_twin.plant.effort_source import EffortSource
from feed_twin.plant.guide_friction import GuideFriction
from feed_twin.plant.mass import Mass
from feed_twin.plant.pmsm import Pmsm
from feed_twin.plant.registry import COMPONENT_TYPES

FIXED_SECTIONS = ("plant", "controller")
# the section the workflow writes beside a fitted model, and its key: the drive gain the
# measured effort was converted with (the nominal one), which a fitted gain must not replace
ANALYSIS_SECTION = "analysis"
REFERENCE_GAIN_KEY = "effort_reference_gain"
# the record's own slots (not the machine's): `analysis.effort_delay_s`, how much later than the
# position the recorder stamps the effort, `position_delay_s` how much later than the command
# it stamps the position, `trace_window_s` the window [s] each sample averages over (absent:
# as the column map's trace_filter says), `effort_ripple_sin`/`_cos` the ripple [effort SI unit]
# once per electrical revolution that offsets on the drive's phase-current sensors leave in the
# recorded effort of a twin without a CurrentSensor of its own. Trace side, outside every loop.
# `command_delay_s`: how much later than the twin's own loops the drive follows the recorded
# command (its setpoint latency, which no user knows): every output of the twin is stamped this
# much later, on top of the channels' own delays. Command side, before every loop.
RECORD_SLOTS = (
    "command_delay_s",
    "effort_delay_s",
    "position_delay_s",
    "trace_window_s",
    "effort_ripple_sin",
    "effort_ripple_cos",
)
RIPPLE_SLOTS = (f"{ANALYSIS_SECTION}.effort_ripple_sin", f"{ANALYSIS_SECTION}.effort_ripple_cos")
# `analysis.pole_pairs`: the motor's pole pairs, for a twin that models the drive as an effort
# source (no Pmsm to carry them): the electrical angle of a phase-current offset's ripple
POLE_PAIRS_KEY = "pole_pairs"
# `analysis.effort_signal: current_q_A`: an effort-source twin whose command is the drive's
# q-current [A] (its EffortSource's gain a torque constant): its effort is that current, as a
# PMSM twin's is (a PMSM axis at a slow record's scale, analysis.record_scale)
EFFORT_SIGNAL_KEY = "effort_signal"
COMMAND_DELAY_SLOT = f"{ANALYSIS_SECTION}.command_delay_s"
EFFORT_DELAY_SLOT = f"{ANALYSIS_SECTION}.effort_delay_s"
POSITION_DELAY_SLOT = f"{ANALYSIS_SECTION}.position_delay_s"
TRACE_WINDOW_SLOT = f"{ANALYSIS_SECTION}.trace_window_s"


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
        masses = self.of_type(Mass.TYPE)
        return f"{masses[-1]}.m" if masses else None

    def friction(self) -> str | None:
        found = self.of_type(GuideFriction.TYPE)
        return found[0] if found else None

    def gain_slot(self) -> str | None:
        found = self.of_type(EffortSource.TYPE)
        return f"{found[0]}.gain" if found else None

    def effort_signal(self) -> str | None:
        """The recorded effort the model's drive command stands for (EFFORT_SIGNAL_KEY), None
        where the model's drive says it (a motor's current, an effort source's force)."""
        given = (self.data.get(ANALYSIS_SECTION) or {}).get(EFFORT_SIGNAL_KEY)
        if given is not None and given != "current_q_A":
            raise ConfigError(
                f"{self.source}: {ANALYSIS_SECTION}.{EFFORT_SIGNAL_KEY} = {given!r}: the only "
                "effort an effort source's command can stand for is 'current_q_A'"
            )
        return given

    def base_period(self) -> float:
        """The controller's base period [s] (the engine's tick)."""
        return float(self.data["controller"]["base_period_s"])

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

    def _declared(self, comp: str, field_name: str) -> tuple[dict[str, Any], Quantity | None]:
        """(the component's YAML params, the quantity its type declares by that name)."""
        entry = self.component(comp)
        kind = COMPONENT_TYPES.get(str(entry.get("type")))
        return entry["params"], None if kind is None else kind.quantity(field_name)

    def has_slot(self, slot: str) -> bool:
        """True for a tie name or a parameter the document holds (not a split tie)."""
        if slot in self.tie_names():
            return True
        comp, _, field_name = slot.partition(".")
        if comp == ANALYSIS_SECTION:
            return field_name in (self.data.get(ANALYSIS_SECTION) or {})
        try:
            params, quantity = self._declared(comp, field_name)
        except LookupError:
            return False
        if quantity is not None:
            return quantity.present(params)
        return field_name in params

    def get(self, slot: str) -> float:
        first = self.tie_members(slot)[0]
        comp, _, field_name = first.partition(".")
        if comp == ANALYSIS_SECTION and field_name in RECORD_SLOTS:
            return float((self.data.get(ANALYSIS_SECTION) or {}).get(field_name, 0.0))
        params, quantity = self._declared(comp, field_name)
        if quantity is not None and quantity.present(params):
            return quantity.read(params)
        if field_name not in params:
            pair = (f"{field_name}_pos", f"{field_name}_neg")
            if all(p in params for p in pair):
                # a tie that a later edit split (Coulomb -> asymmetric): report the mean
                return 0.5 * (float(params[pair[0]]) + float(params[pair[1]]))
            raise LookupError(f"{self.source}: plant.{comp} has no parameter {field_name!r}")
        return float(params[field_name])

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
            params, quantity = new._declared(comp, field_name)
            kind = COMPONENT_TYPES.get(str(new.component(comp).get("type")))
            if quantity is not None and quantity.present(params):
                quantity.write(params, value)
                continue
            # whole-number fields (counts, pole pairs) stay whole numbers in the YAML; a delay in
            # ticks configured as 0 takes a fraction
            keep_int = kind is not None and kind.whole_number(field_name)
            params[field_name] = int(round(value)) if keep_int else float(value)
        return new

    def set_raw(self, component: str, field_name: str, value: Any) -> ModelDoc:
        """Set a component field that is not a fitted slot (a period, a flag, a list)."""
        new = self._copy()
        new.component(component)["params"][field_name] = copy.deepcopy(value)
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
        return self._added(entry, [[f"{entry['name']}.flange", connect_to]])

    def _added(self, entry: dict[str, Any], connect: list[list[str]]) -> ModelDoc:
        new = self._copy()
        new.data["plant"]["components"].append(copy.deepcopy(entry))
        new.data["plant"]["connect"].extend(copy.deepcopy(connect))
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

    def with_component(
        self, base: str, kind: str, params: dict[str, Any], connect: list[list[str]]
    ) -> tuple[ModelDoc, str]:
        """The document with a component of type `kind` named `base` (or `base2`, ...), its
        ports connected as `connect` says (`{name}` in a port stands for its name)."""
        name = self._free_name(base)
        entry = {"name": name, "type": kind, "params": dict(params)}
        wires = [[end.format(name=name) for end in pair] for pair in connect]
        return self._added(entry, wires), name

    def with_table_component(
        self, base: str, kind: str, params: dict[str, Any]
    ) -> tuple[ModelDoc, str]:
        """The document with a component of type `kind` on the table's node (its single port
        connected there), named `base` or `base2`, ...; returns the document and the name."""
        return self.with_component(base, kind, params, [["{name}.flange", self.table_port()]])

    def bus_voltage(self) -> float | None:
        """No-load DC-bus voltage u_0 [V] of the (first) DcBus, None without one."""
        buses = self.of_type(DcBus.TYPE)
        return self.get(f"{buses[0]}.u_0") if buses else None

    def torque_constant(self) -> float | None:
        """The torque constant [N m/A] of the first Pmsm (its `K_t` = 1.5 p psi_pm) or else the
        first DcMotor (its `k`) or else, where the drive command is a current (`effort_signal`),
        the EffortSource's gain; None without any."""
        motors = self.of_type(Pmsm.TYPE)
        if motors:
            return self.get(f"{motors[0]}.K_t")
        motors = self.of_type(DcMotor.TYPE)
        if motors:
            return self.get(f"{motors[0]}.k")
        gain = self.gain_slot()
        return self.get(gain) if gain is not None and self.effort_signal() else None

    def force_per_effort(self, effort_unit: str, *, resisting: bool = True) -> float | None:
        """Newtons at the table per unit of the drive's effort in `effort_unit` (N, N m or A).

        1 for a force; for a torque, the first BallScrew's force per torque (its lead and
        efficiency, plant.ball_screw.BallScrew.force_per_torque: `resisting` as there); for a
        q-current, times the motor's torque constant (the plant's physics, not the
        controller's belief of it in controller.drive). None where the model has no screw, or
        no motor for a current.
        """
        if effort_unit not in ("N", "N m", "A"):
            raise ValueError(f"effort_unit = {effort_unit!r}: must be one of 'N', 'N m', 'A'")
        if effort_unit == "N":
            return 1.0
        screws = self.of_type(BallScrew.TYPE)
        if not screws:
            return None
        screw = BallScrew(
            lead=self.get(f"{screws[0]}.lead"), efficiency=self.get(f"{screws[0]}.efficiency")
        )
        per_torque = screw.force_per_torque(resisting=resisting)
        if effort_unit == "N m":
            return per_torque
        k_t = self.torque_constant()
        return None if k_t is None else k_t * per_torque

    def dump(self, path: str | Path, header: list[str]) -> None:
        """Write the model YAML; a drive gain the fit changed keeps the gain the record's
        effort was converted with (the map's), so the written model reproduces the fit."""
        data = self.data
        g = self.gain_slot()
        if g is not None and self.reference_gain is not None and self.get(g) != self.reference_gain:
            kept = data.get(ANALYSIS_SECTION) or {}  # the record's slots stay
            data = {**data, ANALYSIS_SECTION: {**kept, REFERENCE_GAIN_KEY: self.reference_gain}}
        text = "".join(f"# {line}\n" for line in header)
        text += yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
        Path(path).write_text(text)


def model_of(doc: Document) -> ModelDoc:
    """The ModelDoc behind a document an effect's edit or truth returned (they return the
    document they were given, edited)."""
    if not isinstance(doc, ModelDoc):
        raise TypeError(f"expected a ModelDoc, got {type(doc).__name__}")
    return doc
