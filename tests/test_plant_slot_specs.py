"""Units and ranges of the parameter slots: each field's range is where its component's own
constructor starts refusing it, found by bisection; every slot of the shipped configurations
has a unit."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import pytest

from feed_twin.core.validate import require_positive
from feed_twin.plant.component import Component
from feed_twin.plant.mass import Mass
from feed_twin.plant.sensors import MAX_DELAY_TICKS, LinearScale
from feed_twin.plant.slot_specs import SlotSpecError, describe, slot_specs
from feed_twin.sim.config import load_axis_config

ROOT = Path(__file__).resolve().parent.parent
AXES = [ROOT / "config" / "axis_default.yaml", ROOT / "config" / "emps.yaml"]


def test_a_positive_mass_is_open_at_zero_and_finite():
    spec = slot_specs(Mass(m=200.0))["m"]
    assert (spec.unit, spec.low, spec.low_open, spec.high, spec.high_open) == (
        "kg",
        0.0,
        True,
        math.inf,
        True,
    )
    assert describe(spec) == "> 0 kg and finite"


def test_a_delay_configured_whole_is_a_fraction_bounded_by_the_ring():
    # the field is a float (fractions of a tick are interpolated): a YAML 1 is no whole number
    spec = slot_specs(LinearScale(resolution=1e-8, delay_ticks=1))["delay_ticks"]
    assert (spec.unit, spec.low, spec.high, spec.integer) == ("1", 0.0, MAX_DELAY_TICKS, False)
    assert (spec.low_open, spec.high_open) == (False, False)
    assert describe(spec) == f">= 0 and <= {MAX_DELAY_TICKS}"


@pytest.mark.parametrize("path", AXES, ids=lambda p: p.name)
def test_the_probed_edges_are_the_constructors_edges(path):
    # just inside each bound the component is built, just outside it is refused
    for comp in load_axis_config(path).plant.components.values():
        fields = {f.name for f in dataclasses.fields(comp)}
        for name, spec in slot_specs(comp).items():
            assert spec.unit, f"{type(comp).__name__}.{name}"
            if name not in fields:
                continue
            for bound, is_open, outward in (
                (spec.low, spec.low_open, -math.inf),
                (spec.high, spec.high_open, math.inf),
            ):
                if math.isinf(bound) and not is_open:
                    continue
                if spec.integer:  # integer bounds are closed
                    _build(comp, name, int(bound))
                    with pytest.raises(ValueError):
                        _build(comp, name, int(bound + math.copysign(1, outward)))
                    continue
                inside = math.nextafter(bound, -outward) if is_open else bound
                outside = bound if is_open else math.nextafter(bound, outward)
                _build(comp, name, inside)
                with pytest.raises(ValueError):
                    _build(comp, name, outside)


def _build(comp: Component, name: str, value: float) -> None:
    dataclasses.replace(comp, **{name: value})


@dataclass(frozen=True, kw_only=True)
class _Unitless(Component):
    TYPE = "Unitless"
    PORTS = {}
    k: float  # a stiffness without its unit

    def __post_init__(self) -> None:
        require_positive("k", self.k)


def test_a_slot_without_a_unit_is_named():
    with pytest.raises(SlotSpecError, match=r"^_Unitless.k: no unit \(a field comment"):
        slot_specs(_Unitless(k=1.0))
