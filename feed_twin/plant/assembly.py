"""Assembly of a plant from components and connections, and generation of its glue code.

The assembler
1. joins connected ports into nodes (connecting equates the across variables and sums the
   through variables: the generated code accumulates every force applied at a node in `F_n<k>`);
2. merges mechanical nodes linked by transformers (the ball screw) into one generalized
   coordinate q with a ratio r per node (across_n = r_n * q): the coordinate's effective inertia
   is sum J_i r_i^2 and its generalized force sum r_n F_n, so rigid chains such as the EMPS bench
   are one body without any hand-written reduction;
3. lays out the flat state vector (coordinates, then component states, then energy accumulators)
   and the flat parameter vector (component slots, then derived slots: node ratios and inverse
   effective inertias), each slot with a name and a named constant in the generated source;
4. asks each component to emit its glue stage by stage into a `codegen.Generator`, which reads
   the structure through `PlantModel.view()` (a frozen `plant.view.AssemblyView`) and writes
   the module source (see feed_twin.plant.codegen). The engine (feed_twin.sim.kernel)
   adds the loop and compiles the whole module once per structure.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from feed_twin.core import signals
from feed_twin.core.arrays import FloatArray
from feed_twin.plant.codegen import Generator, acceleration_name, const_name
from feed_twin.plant.component import STAGES, AssemblyError, Component, check_name
from feed_twin.plant.view import AssemblyView, Coordinate

POSITION_LIMIT = 1.0e4  # |q| [m or rad] counted as a runaway
VELOCITY_LIMIT = 1.0e5  # |dq/dt| [m/s or rad/s] counted as a runaway


@dataclass(frozen=True, kw_only=True)
class Node:
    index: int
    kind: str
    ports: tuple[str, ...]  # "component.port"


class PlantModel:
    """An assembled plant: layouts, names and the generated source of its functions.

    Build with `assemble(...)`. The object is immutable after construction; parameter sets are
    plain float64 vectors (`nominal_params()`, `param_vector(overrides)`), states plain vectors
    (`initial_state(...)`).
    """

    def __init__(
        self,
        components: Sequence[tuple[str, Component]],
        connections: Sequence[Sequence[str]],
        *,
        source: str = "<plant>",
        track_energy: bool = False,
    ) -> None:
        self.source = source
        self.track_energy = track_energy
        self.components: dict[str, Component] = {}
        for name, comp in components:
            try:
                check_name(name)
            except ValueError as exc:
                raise AssemblyError(f"{source}: plant.components: {exc}") from None
            if name in self.components:
                raise AssemblyError(f"{source}: plant.{name}: duplicate component name")
            self.components[name] = comp
        # pairs as configured; a pair of another length is reported by _build_nodes
        self.connections: tuple[tuple[str, ...], ...] = tuple(tuple(c) for c in connections)
        self._build_nodes()
        self._build_coordinates()
        self._build_layouts()
        self._generate()

    def _port_kind(self, ref: str, where: str) -> str:
        comp_name, _, port = ref.partition(".")
        if comp_name not in self.components:
            raise AssemblyError(
                f"{self.source}: {where} = {ref!r}: no component named {comp_name!r}; "
                f"components: {', '.join(self.components)}"
            )
        ports = self.components[comp_name].ports()
        if port not in ports:
            raise AssemblyError(
                f"{self.source}: {where} = {ref!r}: {comp_name} "
                f"({self.components[comp_name].TYPE}) has no port {port!r}; "
                f"ports: {', '.join(ports)}"
            )
        return ports[port]

    def _build_nodes(self) -> None:
        parent: dict[str, str] = {}
        kinds: dict[str, str] = {}
        for name, comp in self.components.items():
            for port, kind in comp.ports().items():
                parent[f"{name}.{port}"] = f"{name}.{port}"
                kinds[f"{name}.{port}"] = kind

        def find(a: str) -> str:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        for i, pair in enumerate(self.connections):
            where = f"plant.connect[{i}]"
            if len(pair) != 2:
                raise AssemblyError(f"{self.source}: {where} = {list(pair)!r}: needs two ports")
            ka = self._port_kind(pair[0], where)
            kb = self._port_kind(pair[1], where)
            if ka != kb:
                raise AssemblyError(
                    f"{self.source}: {where} = {list(pair)!r}: cannot connect a {ka} port to a "
                    f"{kb} port"
                )
            parent[find(pair[0])] = find(pair[1])
        groups: dict[str, list[str]] = {}
        for ref in parent:  # insertion order: component order, then port order
            groups.setdefault(find(ref), []).append(ref)
        self.nodes: list[Node] = []
        self.node_of: dict[str, int] = {}
        for ports in groups.values():
            node = Node(index=len(self.nodes), kind=kinds[ports[0]], ports=tuple(ports))
            self.nodes.append(node)
            for ref in ports:
                self.node_of[ref] = node.index
        for node in self.nodes:
            if node.kind in ("dc", "ac3") and len(node.ports) < 2:
                raise AssemblyError(
                    f"{self.source}: plant.connect: the {node.kind} port "
                    f"{', '.join(node.ports)} is not connected to anything"
                )

    def _build_coordinates(self) -> None:
        inertia_nodes: dict[int, list[tuple[str, str, float]]] = {}
        for name, comp in self.components.items():
            for spec in comp.inertias():
                node = self.node_of[f"{name}.{spec.port}"]
                inertia_nodes.setdefault(node, []).append((name, spec.slot, spec.factor))
        self.inertia_nodes = inertia_nodes
        edges: dict[int, list[tuple[int, str, bool, str]]] = {}
        self.lossy_nodes: set[int] = set()
        for name, comp in self.components.items():
            spec = comp.TRANSFORMER
            if spec is None:
                continue
            rot, trans, slot = spec
            a, b = self.node_of[f"{name}.{rot}"], self.node_of[f"{name}.{trans}"]
            expr = f"p[{const_name('P_', f'{name}.{slot}')}]"
            edges.setdefault(a, []).append((b, expr, True, name))
            edges.setdefault(b, []).append((a, expr, False, name))
            if comp.lossy:
                if b in inertia_nodes:
                    raise AssemblyError(
                        f"{self.source}: plant.{name}.efficiency = "
                        f"{comp.slots()['efficiency']!r}: a lossy screw needs a massless "
                        f"translational flange, but {name}.{trans} carries a mass; put an "
                        "AxialCompliance between the screw and the nut"
                    )
                self.lossy_nodes.add(b)
        mech = [n for n in self.nodes if n.kind in ("rotational", "translational")]
        seen: set[int] = set()
        self.coordinates: list[Coordinate] = []
        self.coordinate_of: dict[int, int] = {}
        for start in mech:
            if start.index in seen:
                continue
            ratios: dict[int, str] = {start.index: "1.0"}
            used: set[str] = set()
            order = [start.index]
            queue = [start.index]
            seen.add(start.index)
            while queue:
                n = queue.pop()
                for m, expr, forward, via in edges.get(n, []):
                    if via in used:
                        continue
                    used.add(via)
                    r = f"({ratios[n]} * {expr})" if forward else f"({ratios[n]} / {expr})"
                    if m in ratios:
                        raise AssemblyError(
                            f"{self.source}: plant.connect: transformers form a loop at "
                            f"{', '.join(self.nodes[m].ports)}"
                        )
                    ratios[m] = r
                    order.append(m)
                    seen.add(m)
                    queue.append(m)
            bodies = [n for n in order if n in inertia_nodes]
            if not bodies:
                ports = [p for n in order for p in self.nodes[n].ports]
                raise AssemblyError(
                    f"{self.source}: plant.connect: the flanges {', '.join(ports)} carry no "
                    "inertia (massless node); add a body or connect them rigidly to one"
                )
            # re-reference the coordinate to the first body so its states carry that body's name
            ref = bodies[0]
            ref_expr = ratios[ref]
            ratios = {
                n: "1.0" if n == ref else f"({expr} / {ref_expr})" for n, expr in ratios.items()
            }
            body = inertia_nodes[ref][0][0]
            kind = self.nodes[ref].kind
            pos, vel = ("phi", "omega") if kind == "rotational" else ("s", "v")
            coord = Coordinate(
                index=len(self.coordinates),
                name=body,
                kind=kind,
                nodes=tuple(order),
                ratios=ratios,
                position_state=f"{body}.{pos}",
                velocity_state=f"{body}.{vel}",
            )
            self.coordinates.append(coord)
            for n in order:
                self.coordinate_of[n] = coord.index

    def _build_layouts(self) -> None:
        states: list[tuple[str, str, float]] = []
        for c in self.coordinates:
            unit_p, unit_v = ("rad", "rad/s") if c.kind == "rotational" else ("m", "m/s")
            states.append((c.position_state, unit_p, POSITION_LIMIT))
            states.append((c.velocity_state, unit_v, VELOCITY_LIMIT))
        for name, comp in self.components.items():
            for spec in comp.states():
                states.append((f"{name}.{spec.name}", spec.unit, spec.limit))
        self._core_states = states
        self.core_state_names: tuple[str, ...] = tuple(s for s, _, _ in states)
        params: list[tuple[str, float]] = []
        for name, comp in self.components.items():
            for slot, value in comp.slots().items():
                params.append((f"{name}.{slot}", value))
        self._component_params = params
        derived: list[str] = []
        for c in self.coordinates:
            for n in c.nodes:
                derived.append(f"derived.ratio_n{n}")
            derived.append(f"derived.inv_inertia.{c.name}")
        self._derived = derived
        self.param_names: tuple[str, ...] = tuple(n for n, _ in params) + tuple(derived)
        self.param_index = {n: i for i, n in enumerate(self.param_names)}
        self.ext_names: tuple[str, ...] = tuple(
            name for name, comp in self.components.items() if comp.HAS_INPUT
        )

    def view(self) -> AssemblyView:
        """The graph and layouts as the code generator reads them."""
        return AssemblyView(
            source=self.source,
            track_energy=self.track_energy,
            component_names=tuple(self.components),
            node_of=dict(self.node_of),
            coordinates=tuple(self.coordinates),
            inertia_nodes={n: tuple(specs) for n, specs in self.inertia_nodes.items()},
            core_state_names=self.core_state_names,
            param_names=self.param_names,
            ext_names=self.ext_names,
        )

    def _generate(self) -> None:
        gen = Generator(self.view())
        for stage in STAGES:
            gen.stage = stage
            for name, comp in self.components.items():
                gen.current = name
                comp.emit(stage, gen)
        self.state_names: tuple[str, ...] = self.core_state_names + tuple(gen.energy_states)
        self.state_units: tuple[str, ...] = tuple(u for _, u, _ in self._core_states) + (
            ("J",) * len(gen.energy_states)
        )
        self.state_limits = np.array(
            [lim for _, _, lim in self._core_states] + [math.inf] * len(gen.energy_states)
        )
        self.state_index = {n: i for i, n in enumerate(self.state_names)}
        self.energy_kinds: dict[str, str] = dict(gen.energy_kinds)
        kinetic = [f"stored.{c.name}.kinetic" for c in self.coordinates]
        accelerations = [acceleration_name(c) for c in self.coordinates]
        self.aux_names: tuple[str, ...] = (
            tuple(gen.aux_names) + tuple(kinetic) + tuple(accelerations)
        )
        self.stored_names: tuple[str, ...] = tuple(gen.stored_names) + tuple(kinetic)
        self.meas_delay_slots = dict(gen.meas_delays)
        self.switching_inverter = next((n for n, c in self.components.items() if c.switching), None)
        self.signal_names: frozenset[str] = frozenset(gen.signal_names)  # MEAS_*/OUT_* it imports
        self.source_code = gen.module_source()
        self.structure_digest = hashlib.sha256(self.source_code.encode()).hexdigest()[:16]

    def nominal_params(self) -> FloatArray:
        """The parameter vector of the components as configured (derived slots filled)."""
        return self.param_vector()

    def param_vector(self, overrides: Mapping[str, float] | None = None) -> FloatArray:
        """Nominal parameters with named slots replaced, derived slots recomputed."""
        p = np.zeros(len(self.param_names))
        for i, (_, value) in enumerate(self._component_params):
            p[i] = value
        for name, value in (overrides or {}).items():
            if name not in self.param_index or name.startswith("derived."):
                raise KeyError(f"parameter {name!r}: unknown; slots: {', '.join(self.param_names)}")
            p[self.param_index[name]] = float(value)
        return self.fill_derived(p)

    def fill_derived(self, p: FloatArray) -> FloatArray:
        """Recompute the derived slots of p in place (also the batch form p[N, P]); returns p."""
        namespace = self.namespace()
        rows = p.reshape(-1, p.shape[-1])
        for row in rows:
            namespace["fill_derived"](row)
            inv = [row[self.param_index[f"derived.inv_inertia.{c.name}"]] for c in self.coordinates]
            for c, value in zip(self.coordinates, inv, strict=True):
                if not (math.isfinite(value) and value > 0.0):
                    bodies = [
                        f"{comp}.{slot}"
                        for n in c.nodes
                        for comp, slot, _ in self.inertia_nodes.get(n, [])
                    ]
                    raise ValueError(
                        f"coordinate {c.name}: effective inertia {float(1.0 / value)!r} is not "
                        f"positive (from {', '.join(bodies)})"
                    )
        return p

    def initial_state(self, positions: Mapping[str, float] | None = None) -> FloatArray:
        """State at rest with all springs relaxed; `positions` sets bodies, e.g. {"table": 0.1}.

        A position given for one body moves every coordinate linked to it through two-port
        force elements (couplings, compliances, backlash) so that no spring starts stretched.
        """
        x = np.zeros(len(self.state_names))
        for c, (value, chain) in self._position_chains(positions or {}).items():
            for multiply, divide in chain:
                value = value * multiply / divide
            x[self.state_index[self.coordinates[c].position_state]] = value
        return x

    def position_chains(self, body: str) -> dict[str, tuple[tuple[float, float], ...]]:
        """Position state -> the (multiply, divide) ratio pairs, in order, that carry a position
        of `body` to it in `initial_state` (x = ((s * m1) / d1) * m2 / d2 ...); an importer that
        sets the start position (the FMU) repeats the same operations, so the same bits."""
        chains = self._position_chains({body: 0.0})
        return {self.coordinates[c].position_state: chain for c, (_, chain) in chains.items()}

    def _position_chains(
        self, positions: Mapping[str, float]
    ) -> dict[int, tuple[float, tuple[tuple[float, float], ...]]]:
        """Coordinate index -> (the body position it follows, the ratio pairs that carry it)."""
        p = self.nominal_params()
        links: dict[int, list[tuple[int, float, float]]] = {}
        for name, comp in self.components.items():
            ports = [
                pt for pt in comp.ports() if comp.ports()[pt] in ("rotational", "translational")
            ]
            if len(ports) != 2 or comp.TRANSFORMER:
                continue
            na, nb = (self.node_of[f"{name}.{pt}"] for pt in ports)
            ca, cb = self.coordinate_of[na], self.coordinate_of[nb]
            ra, rb = self._ratio_value(na, p), self._ratio_value(nb, p)
            links.setdefault(ca, []).append((cb, ra, rb))
            links.setdefault(cb, []).append((ca, rb, ra))
        chains: dict[int, tuple[float, tuple[tuple[float, float], ...]]] = {}
        for body, value in positions.items():
            matches = [c for c in self.coordinates if c.name == body]
            if not matches:
                raise KeyError(
                    f"initial position of {body!r}: no coordinate of that name; coordinates: "
                    f"{', '.join(c.name for c in self.coordinates)}"
                )
            start = matches[0].index
            chains[start] = (float(value), ())
            queue = [start]
            while queue:
                c = queue.pop()
                for other, r_self, r_other in links.get(c, []):
                    if other not in chains:
                        chains[other] = (chains[c][0], chains[c][1] + ((r_self, r_other),))
                        queue.append(other)
        return chains

    def _ratio_value(self, node: int, p: FloatArray) -> float:
        return float(p[self.param_index[f"derived.ratio_n{node}"]])

    def namespace(self) -> dict[str, Any]:
        """The plant functions executed as plain Python (un-jitted numba callees inside).

        The generated module's globals: their types are the generated text's (`rhs`, `outputs`,
        `sense`, `angles`, ... with the signatures `codegen` writes), which no checker can see.
        """
        if not hasattr(self, "_namespace"):
            # the same source, with njit as the identity: plain Python calling the jitted
            # component functions, for the reference integration and linearisation
            namespace: dict[str, Any] = {}
            text = self.source_code.replace("from numba import njit\n", "")
            namespace["njit"] = _identity_decorator
            exec(compile(text, f"<plant {self.structure_digest}>", "exec"), namespace)
            self._namespace = namespace
        return self._namespace

    def linearize(
        self,
        x: FloatArray,
        p: FloatArray,
        out: FloatArray | None = None,
        ext: FloatArray | None = None,
        *,
        states: Sequence[str] | None = None,
        rel_step: float = 1e-6,
    ) -> FloatArray:
        """Jacobian d(rhs)/dx at (x, p) by central differences over the named states."""
        rhs = self.namespace()["rhs"]
        out = np.zeros(signals.OUT_SIZE) if out is None else out
        ext = np.zeros(max(len(self.ext_names), 1)) if ext is None else ext
        sw = np.zeros(3)
        names = list(states) if states is not None else list(self.state_names)
        idx = [self.state_index[n] for n in names]
        jac = np.zeros((len(idx), len(idx)))
        f_hi, f_lo = np.zeros(len(x)), np.zeros(len(x))
        for j, i in enumerate(idx):
            step = rel_step * max(1.0, abs(x[i]))
            xp, xm = x.copy(), x.copy()
            xp[i] += step
            xm[i] -= step
            rhs(0.0, xp, p, out, ext, sw, f_hi)
            rhs(0.0, xm, p, out, ext, sw, f_lo)
            jac[:, j] = (f_hi[idx] - f_lo[idx]) / (2.0 * step)
        return jac

    def with_params(self, **changes: Mapping[str, object]) -> PlantModel:
        """A model whose components are replaced by `dataclasses.replace(component, **fields)`."""
        comps = [
            (n, dataclasses.replace(c, **changes[n]) if n in changes else c)
            for n, c in self.components.items()
        ]
        return PlantModel(
            comps, self.connections, source=self.source, track_energy=self.track_energy
        )

    def with_energy_tracking(self, track_energy: bool = True) -> PlantModel:
        """The same plant whose state also integrates every source and loss power [J]
        (states `energy.<component>.<name>`, for energy balances); off by default for speed."""
        return PlantModel(
            list(self.components.items()),
            self.connections,
            source=self.source,
            track_energy=track_energy,
        )


_F = TypeVar("_F", bound=Callable[..., object])


def _identity_decorator(**_options: object) -> Callable[[_F], _F]:
    """`@njit(...)` of the generated text, run as plain Python: the function itself."""

    def identity(f: _F) -> _F:
        return f

    return identity


def assemble(
    components: Sequence[tuple[str, Component]],
    connections: Sequence[Sequence[str]],
    *,
    source: str = "<plant>",
    track_energy: bool = False,
) -> PlantModel:
    """Build a PlantModel from (name, component) pairs and [port, port] connections."""
    return PlantModel(components, connections, source=source, track_energy=track_energy)
