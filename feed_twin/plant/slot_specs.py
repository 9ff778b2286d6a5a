"""Unit and physical range of every parameter slot of a component, for callers that set slots
one by one past the constructor (the FMU's fmi2SetReal, feed_twin.native.fmu).

A slot that is a field takes its unit from the field's comment (`m: float  # mass [kg]`) and its
range from the component's own `__post_init__` checks: the constructor is asked, by bisection
over the ordered doubles (or integers) between the configured value and +-infinity, where it
starts refusing the field, the other fields as configured. So the range cannot drift from the
checks a YAML file meets, and `m = 0` is refused where `Mass` refuses it. A slot computed from
several fields (`ScrewShaft.k_t`) declares both in the component's `COMPUTED_SLOTS`.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import struct
from collections.abc import Callable
from functools import cache

from feed_twin.plant.component import Component, SlotSpec

_SIGN = 1 << 63
_WHOLE = 1 << 62  # the integer probes' reach, either side


class SlotSpecError(LookupError):
    """A slot without a declared unit."""


def slot_specs(component: Component) -> dict[str, SlotSpec]:
    """Slot name -> unit and range, for every slot of `component` (`component.slots()`)."""
    units = field_units(type(component))
    fields = {f.name for f in dataclasses.fields(component)}
    specs: dict[str, SlotSpec] = {}
    for name in component.slots():
        computed = type(component).computed_slot(name)
        if computed is not None:
            specs[name] = computed
        elif name in fields and name in units:
            specs[name] = _probed(component, name, units[name])
        else:
            raise SlotSpecError(
                f"{type(component).__name__}.{name}: no unit (a field comment `# ... [unit]` "
                "or a COMPUTED_SLOTS entry)"
            )
    return specs


@cache
def field_units(cls: type) -> dict[str, str]:
    """Field -> unit from the `# ... [unit]` comments of a dataclass and its bases ("-" and
    "bit" are a pure number, "1")."""
    units: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        try:
            text = inspect.getsource(klass)
        except (OSError, TypeError):
            continue
        for field, unit in re.findall(r"^    (\w+): [^#\n]*#[^\n\[]*\[([^\]]+)\]", text, re.M):
            units[field] = "1" if unit in ("-", "bit") else unit
    return units


def describe(spec: SlotSpec) -> str:
    """The range in words, with the unit: "> 0 kg", "a whole number >= 0 and <= 256"."""
    unit = "" if spec.unit == "1" else f" {spec.unit}"
    parts: list[str] = []
    if spec.low > -math.inf:
        parts.append(f"{'>' if spec.low_open else '>='} {_number(spec.low)}{unit}")
    if spec.high < math.inf:
        parts.append(f"{'<' if spec.high_open else '<='} {_number(spec.high)}{unit}")
    if (spec.low == -math.inf and spec.low_open) or (spec.high == math.inf and spec.high_open):
        parts.append("finite")
    text = " and ".join(parts) or "any value"
    return f"a whole number {text}" if spec.integer else text


def _number(x: float) -> str:
    return f"{x:g}" if float(f"{x:g}") == x else repr(x)


def _probed(component: Component, name: str, unit: str) -> SlotSpec:
    value = getattr(component, name)
    integer = type(component).whole_number(name)

    def accepts(v: float) -> bool:
        try:
            dataclasses.replace(component, **{name: int(v) if integer else v})
        except (ValueError, TypeError, OverflowError):
            return False
        return True

    if integer:
        low = _integer_edge(accepts, value, -_WHOLE)
        high = _integer_edge(accepts, value, _WHOLE)
        return SlotSpec(unit=unit, low=low, high=high, integer=True)
    low, low_open = _float_edge(accepts, float(value), -math.inf)
    high, high_open = _float_edge(accepts, float(value), math.inf)
    return SlotSpec(unit=unit, low=low, low_open=low_open, high=high, high_open=high_open)


def _integer_edge(accepts: Callable[[float], bool], inside: int, outside: int) -> float:
    """The last accepted integer from `inside` towards `outside` (+-inf when all are)."""
    if accepts(outside):
        return math.copysign(math.inf, outside)
    while abs(outside - inside) > 1:
        middle = (inside + outside) // 2
        inside, outside = (middle, outside) if accepts(middle) else (inside, middle)
    return float(inside)


def _float_edge(
    accepts: Callable[[float], bool], inside: float, outside: float
) -> tuple[float, bool]:
    """(bound, open) where the accepted values from `inside` towards `outside` end: the last
    accepted double, or the first refused one when that is the rounder number (0 for > 0)."""
    if accepts(outside):
        return outside, False
    a, r = _ordered(inside), _ordered(outside)
    while abs(r - a) > 1:
        middle = (a + r) // 2
        a, r = (middle, r) if accepts(_double(middle)) else (a, middle)
    last, first = _double(a), _double(r)
    if len(repr(first)) < len(repr(last)):
        return first, True
    return last, False


def _ordered(x: float) -> int:
    """The double as an integer that orders as the doubles do (-0.0 and 0.0 are one)."""
    bits = struct.unpack("<q", struct.pack("<d", x))[0]
    return bits if bits >= 0 else -(bits & (_SIGN - 1))


def _double(i: int) -> float:
    bits = i if i >= 0 else (-i) | _SIGN
    return struct.unpack("<d", struct.pack("<Q", bits))[0]


# unit suffixes of the workflow's report names (m_kg, F_v_N_s_m, heating_K_m), longest first
_REPORT_SUFFIXES = (
    ("_N_s_m", "N s/m"),
    ("_per_s", "1/s"),
    ("_m_s", "m/s"),
    ("_N_m", "N/m"),
    ("_K_m", "K/m"),
    ("_Nm", "N m"),
    ("_kg", "kg"),
    ("_rad", "rad"),
    ("_N", "N"),
    ("_s", "s"),
    ("_m", "m"),
    ("_A", "A"),
    ("_V", "V"),
)


def report_unit(name: str) -> str:
    """The unit of a fitted parameter the discrepancy workflow reports: its name's suffix
    (`F_c_N`), else the unit of the component field of that name (`F_v_pos`: N s/m) when every
    component type that has the field agrees on it, else ""."""
    for suffix, unit in _REPORT_SUFFIXES:
        if name.endswith(suffix) and len(name) > len(suffix):
            return unit
    from feed_twin.plant.registry import COMPONENT_TYPES

    units = {field_units(cls).get(name) for cls in COMPONENT_TYPES.values()} - {None}
    return units.pop() if len(units) == 1 else ""  # type: ignore[return-value]


def with_unit(name: str, value: float, digits: int = 5) -> str:
    """`F_v_pos = 168.7 N s/m`: a fitted parameter as a report shows it."""
    unit = report_unit(name)
    return f"{name} = {value:.{digits}g}" + (f" {unit}" if unit and unit != "1" else "")
