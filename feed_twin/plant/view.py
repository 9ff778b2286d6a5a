"""What the code generator reads of an assembled plant: its graph and layouts, frozen.

The assembler (feed_twin.plant.assembly) builds an `AssemblyView` once the nodes, coordinates
and slot layouts are known and hands it to `codegen.Generator`; the generator never sees the
assembler itself, so the dependency runs one way: assembly -> codegen -> view.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass


@dataclass(frozen=True, kw_only=True)
class Coordinate:
    """A generalized coordinate: mechanical nodes moving rigidly together."""

    index: int
    name: str  # the body that names it, e.g. "motor" -> states motor.phi, motor.omega
    kind: str  # kind of the reference node: rotational or translational
    nodes: tuple[int, ...]
    ratios: dict[int, str]  # node index -> Python expression of r_n in p[...] slots
    position_state: str
    velocity_state: str


InertiaSpec = tuple[str, str, float]  # (component, parameter slot, share of the slot's value)


@dataclass(frozen=True, kw_only=True)
class AssemblyView:
    """The assembled structure as the generated code needs it (no components' equations)."""

    source: str  # the configuration file, for error messages
    track_energy: bool  # integrate every source and loss power into an energy state [J]
    component_names: tuple[str, ...]  # in assembly order (noise channel keys follow it)
    node_of: Mapping[str, int]  # "component.port" -> node index
    coordinates: tuple[Coordinate, ...]
    inertia_nodes: Mapping[int, tuple[InertiaSpec, ...]]  # node index -> inertias on it
    core_state_names: tuple[str, ...]  # coordinates, then component states (energies follow)
    param_names: tuple[str, ...]  # component slots, then derived slots
    ext_names: tuple[str, ...]  # components with an external input channel
