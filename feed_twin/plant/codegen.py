"""Generation of a plant's glue code from what its components emit.

`Generator` is the Emitter the assembler (feed_twin.plant.assembly) hands to every component,
stage by stage; it reads the assembled structure through an `AssemblyView` (feed_twin.plant.view)
only. From the collected lines it writes one Python module: the slot constants, three
functions from the same lines, `rhs` (derivatives; also as `rhs_tuple`, derivatives returned),
`outputs` (auxiliary signals, powers, stored energies) and `sense` (sensor samples, reading the
tick's standard normal samples, the tuple `noise` that `draw_noise(p, seed, k)` drew or
`pick_noise(p, row)` took from a row of `standard_normals`), plus `fill_derived(p)` and
`angles(t, x, p)`.

Angles (`Emitter.angle`): `angles` returns (theta, cos, sin) of every declared angle at a state,
flat in one tuple `trig`. `rhs` and `outputs` take sine and cosine of their own state; `sense`
reads them from the `trig` of the same state, which the loop evaluates once per tick; of the RK4
stages' derivatives, `rhs_tuple_start` (the tick's first stage, at that state) does too, and
`rhs_tuple` rotates the tick's pair by the increment (`sincos_near`).
"""

from __future__ import annotations

import re

from feed_twin.plant.component import STAGES, AssemblyError, Emitter
from feed_twin.plant.view import AssemblyView, Coordinate

NOISE_CHANNELS_PER_COMPONENT = 8
SIGNALS = "feed_twin.core.signals"  # the module of the MEAS_*/OUT_* slots the code indexes
SENSE_STAGES = ("currents", "dc_current", "dc_voltage", "sense")


def acceleration_name(c: Coordinate) -> str:
    """Name of a coordinate's acceleration output: `<body>.a` [m/s^2] or `<body>.alpha`."""
    return f"{c.name}.{'alpha' if c.kind == 'rotational' else 'a'}"


def const_name(prefix: str, name: str) -> str:
    """The generated source's constant for a slot name: P_MOTOR_R_S for motor.R_s."""
    return prefix + re.sub(r"[^A-Za-z0-9]", "_", name).upper()


class Generator(Emitter):
    """Collects the lines of the generated functions while components emit."""

    def __init__(self, view: AssemblyView) -> None:
        self.m = view
        self._param_slots = frozenset(view.param_names)
        self.current: str | None = None
        # (kind, code, stage); kind: all, dx, aux, meas
        self.lines: list[tuple[str, str, str]] = []
        self.stage = STAGES[0]
        self.imports: dict[str, str] = {}
        self.energy_states: list[str] = []
        self.energy_kinds: dict[str, str] = {}
        self.aux_names: list[str] = []
        self.stored_names: list[str] = []
        self.meas_delays: dict[str, str] = {}
        self.signal_names: set[str] = set()
        self.node_scale: dict[int, str] = {}
        self.noise_channels: dict[int, str] = {}  # channel key -> scale that switches it on
        self.angles: list[tuple[str, str]] = []  # (expression, local prefix) of each angle
        self.comp_index = {n: i for i, n in enumerate(view.component_names)}

    def _add(self, item: tuple[str, str]) -> None:
        self.lines.append((item[0], item[1], self.stage))

    def _name(self) -> str:
        assert self.current is not None
        return self.current

    def p(self, slot: str) -> str:
        full = f"{self._name()}.{slot}"
        if full not in self._param_slots:
            raise KeyError(f"{full}: no such parameter slot")
        return f"p[{const_name('P_', full)}]"

    def x(self, state: str) -> str:
        return f"x[{const_name('X_', f'{self._name()}.{state}')}]"

    def d(self, state: str, expr: str) -> None:
        self._add(("dx", f"dx[{const_name('X_', f'{self._name()}.{state}')}] = {expr}"))

    def local(self, name: str) -> str:
        return f"{self._name()}__{name}"

    def line(self, code: str) -> None:
        self._add(("all", code))

    def call(self, targets: tuple[str, ...], func: str, args: tuple[str, ...]) -> None:
        module, _, fname = func.rpartition(".")
        alias = f"_{module.rsplit('.', 1)[-1]}_{fname}"
        self.imports[alias] = f"from {module} import {fname} as {alias}"
        lhs = ", ".join(targets)
        self._add(("all", f"{lhs} = {alias}({', '.join(args)})"))

    def _node(self, port: str) -> int:
        return self.m.node_of[f"{self._name()}.{port}"]

    def across(self, port: str) -> tuple[str, str]:
        n = self._node(port)
        return f"s_n{n}", f"v_n{n}"

    def apply(self, port: str, expr: str) -> None:
        self._add(("all", f"F_n{self._node(port)} += {expr}"))

    def node_force(self, port: str) -> str:
        return f"F_n{self._node(port)}"

    def scale_node(self, port: str, expr: str) -> None:
        self.node_scale[self._node(port)] = expr

    def el(self, port: str, var: str) -> str:
        return f"e{self._node(port)}_{var}"

    def drive(self, slot: str) -> str:
        self.signal_names.add(slot)
        return f"out[{slot}]"

    def switch(self, phase: int) -> str:
        return f"sw[{phase}]"

    def ext(self) -> str:
        return f"ext[{const_name('EXT_', self._name())}]"

    def aux(self, name: str, expr: str) -> None:
        full = f"{self._name()}.{name}"
        self.aux_names.append(full)
        self._add(("aux", f"aux[{const_name('A_', full)}] = {expr}"))

    def power(self, kind: str, name: str, expr: str) -> None:
        full = f"energy.{self._name()}.{name}"
        self.energy_kinds[full] = kind
        if self.m.track_energy:
            self.energy_states.append(full)
            self._add(("dx", f"dx[{const_name('X_', full)}] = {expr}"))
        self.aux(f"power.{name}", expr)

    def stored(self, name: str, expr: str) -> None:
        full = f"stored.{self._name()}.{name}"
        self.stored_names.append(full)
        self.aux_names.append(full)
        self._add(("aux", f"aux[{const_name('A_', full)}] = {expr}"))

    def meas(self, slot: str, expr: str, delay: str = "0") -> None:
        if slot in self.meas_delays:
            raise AssemblyError(
                f"{self.m.source}: plant.{self._name()}: a second sensor for {slot}"
            )
        self.signal_names.add(slot)
        self.meas_delays[slot] = self._name()
        self._add(("meas", f"meas[{slot}] = {expr}"))
        self._add(("meas", f"mdelay[{slot}] = {delay}"))
        if "quantize_floor" in expr:
            self.imports["quantize_floor"] = "from feed_twin.plant.sensors import quantize_floor"
        if "adc(" in expr:
            self.imports["adc"] = "from feed_twin.plant.sensors import adc"

    def noise(self, channel: int, scale: str) -> str:
        # `draw_noise` returns the tick's samples, the tuple `noise` the loop hands to `sense`;
        # the key of a channel depends on its component's position only
        self.imports["standard_normal"] = "from feed_twin.plant.noise import standard_normal"
        key = self.comp_index[self._name()] * NOISE_CHANNELS_PER_COMPONENT + channel
        self.noise_channels.setdefault(key, scale)
        return f"{scale} * noise[{list(self.noise_channels).index(key)}]"

    def angle(self, expr: str) -> tuple[str, str]:
        if any(prefix == self.local("") for _, prefix in self.angles):
            raise AssemblyError(
                f"{self.m.source}: plant.{self._name()}: declares a second angle "
                "(a component has at most one: its locals cos and sin)"
            )
        self.angles.append((expr, self.local("")))
        self.imports["sincos"] = "from feed_twin.core.trig import sincos, sincos_near"
        self._add(("angle", str(len(self.angles) - 1)))
        return self.local("cos"), self.local("sin")

    def _angle_lines(self, function: str, i: int) -> list[str]:
        """The lines that set angle i's <prefix>cos and <prefix>sin in one generated function."""
        expr, prefix = self.angles[i]
        theta, pair = f"{prefix}theta", f"{prefix}cos, {prefix}sin"
        if function in ("sense", "rhs_tuple_start"):  # the loop's trig is of the same state
            return [f"{pair} = trig[{3 * i + 1}], trig[{3 * i + 2}]"]
        if function == "rhs_tuple":  # an RK4 stage: the tick's pair, rotated
            ref = ", ".join(f"trig[{3 * i + k}]" for k in range(3))
            return [f"{theta} = {expr}", f"{pair} = sincos_near({theta}, {ref})"]
        return [f"{theta} = {expr}", f"{pair} = sincos({theta})"]

    def _angles(self) -> list[str]:
        """`angles(t, x, p)`: (theta, cos, sin) of each declared angle, flat; (0.0,) for none."""
        lines = list(self._preamble())
        items: list[str] = []
        for i, (_, prefix) in enumerate(self.angles):
            lines += self._angle_lines("angles", i)
            items += [f"{prefix}theta", f"{prefix}cos", f"{prefix}sin"]
        return [
            "",
            "# the Park angles at the start of a tick: `sense` and the RK4 stages start from them",
            '@njit(cache=True, inline="always", error_model="numpy")',
            "def angles(t, x, p):",
            *(f"    {code}" for code in lines),
            f"    return ({', '.join(items or ['0.0'])},)",
        ]

    def _reexpand(self, lines: list[str], function: str) -> list[str]:
        """`lines` of `rhs` with each angle's lines as `function` writes them."""
        full = {self._angle_lines("rhs", i)[1]: i for i in range(len(self.angles))}
        out: list[str] = []
        for code in lines:
            if code in full:
                out += self._angle_lines(function, full[code])[-1:]
            else:
                out.append(code)
        return out

    @staticmethod
    def _first_forces(lines: list[str]) -> list[str]:
        """`F_n = 0.0 ... F_n += a` written as `F_n = a`: IEEE arithmetic may not drop the
        addition of 0.0 itself (it turns -0.0 into +0.0), so each node would pay one per call."""
        out = list(lines)
        for i, code in enumerate(lines):
            match = re.fullmatch(r"(F_n\d+) = 0\.0", code)
            if not match:
                continue
            name = match.group(1)
            token = re.compile(rf"\b{name}\b")
            first = next((j for j in range(i + 1, len(lines)) if token.search(lines[j])), None)
            if first is not None and lines[first].startswith(f"{name} += "):
                out[i] = ""
                out[first] = f"{name} = {lines[first][len(name) + 4 :]}"
        return [code for code in out if code]

    def _rhs_tuple(self, rhs_lines: list[str], name: str) -> list[str]:
        """`rhs` again from the same lines, the derivatives returned as a tuple instead of stored.

        The compiled loop keeps the state and the RK4 stages in registers with it: numba's arrays
        may alias, so with dx and stage vectors in memory LLVM reloaded them around every store.
        """
        slots = [const_name("X_", s) for s in self.m.core_state_names] + [
            const_name("X_", s) for s in self.energy_states
        ]
        lines: list[str] = []
        assigned: set[str] = set()
        for code in rhs_lines:
            match = re.fullmatch(r"dx\[(X_\w+)\] = (.*)", code)
            if match:
                assigned.add(match.group(1))
                code = f"d_{match.group(1)} = {match.group(2)}"
            lines.append(code)
        lines = [f"d_{slot} = 0.0" for slot in slots if slot not in assigned] + lines
        return [
            "",
            '@njit(cache=True, inline="always", error_model="numpy")',
            f"def {name}(t, x, p, out, ext, sw, trig):",
            *(f"    {code}" for code in lines),
            f"    return ({', '.join(f'd_{slot}' for slot in slots)},)",
        ]

    def _draw_noise(self) -> list[str]:
        """`draw_noise(p, seed, k)`: the tick's samples as a tuple, a channel switched off (its
        scale 0) giving 0; `standard_normals(seed, k0, n, table)`: the standard normal samples of
        n ticks, parameters aside (run_batch draws them once for the sets that share a seed);
        `pick_noise(p, row)`: a tick's samples from such a row, the same doubles as
        `draw_noise`. A tuple, not an array: the loop stores nothing that could alias the
        arrays it reads."""
        channels = list(self.noise_channels.items())
        draw = [
            f"standard_normal(seed, k, {key}) if {scale} != 0.0 else 0.0" for key, scale in channels
        ]
        pick = [f"row[{i}] if {scale} != 0.0 else 0.0" for i, (_, scale) in enumerate(channels)]
        table = [
            f"table[j, {i}] = standard_normal(seed, k0 + j, {key})"
            for i, (key, _) in enumerate(channels)
        ]
        return [
            "",
            "# standard normal samples of one tick: (seed, tick, channel) alone determine them",
            '@njit(cache=True, inline="always", error_model="numpy")',
            "def draw_noise(p, seed, k):",
            f"    return {'(' + ''.join(f'{d}, ' for d in draw).rstrip() + ')'}",
            "",
            '@njit(cache=True, error_model="numpy")',
            "def standard_normals(seed, k0, n, table):",
            "    for j in range(n):",
            *(f"        {code}" for code in table or ["pass"]),
            "    return None",
            "",
            '@njit(cache=True, inline="always", error_model="numpy")',
            "def pick_noise(p, row):",
            f"    return {'(' + ''.join(f'{d}, ' for d in pick).rstrip() + ')'}",
        ]

    def _constants(self) -> list[str]:
        m = self.m
        out = ["# state slots"]
        names = [*m.core_state_names, *self.energy_states]
        out += [f"{const_name('X_', n)} = {i}" for i, n in enumerate(names)]
        out.append(f"N_X = {len(names)}")
        out.append("# parameter slots")
        out += [f"{const_name('P_', n)} = {i}" for i, n in enumerate(m.param_names)]
        out.append(f"N_P = {len(m.param_names)}")
        out.append(f"N_NOISE = {len(self.noise_channels)}  # normal samples per tick")
        # a sample is standard_normal(seed, tick, key): plants whose keys agree draw the same
        out.append(f"NOISE_KEYS = {tuple(self.noise_channels)!r}  # channel keys, in column order")
        out.append("# auxiliary outputs")
        kinetic = [f"stored.{c.name}.kinetic" for c in m.coordinates]
        aux = self.aux_names + kinetic + [acceleration_name(c) for c in m.coordinates]
        out += [f"{const_name('A_', n)} = {i}" for i, n in enumerate(aux)]
        out.append(f"N_A = {len(aux)}")
        out.append("# external inputs")
        out += [f"{const_name('EXT_', n)} = {i}" for i, n in enumerate(m.ext_names)]
        out.append(f"N_EXT = {max(len(m.ext_names), 1)}")
        return out

    def _preamble(self) -> list[str]:
        m = self.m
        lines: list[str] = []
        for c in m.coordinates:
            q = f"x[{const_name('X_', c.position_state)}]"
            w = f"x[{const_name('X_', c.velocity_state)}]"
            lines.append(f"q{c.index} = {q}")
            lines.append(f"w{c.index} = {w}")
            for n in c.nodes:
                if c.ratios[n] == "1.0":
                    lines.append(f"s_n{n} = q{c.index}")
                    lines.append(f"v_n{n} = w{c.index}")
                else:
                    r = f"p[{const_name('P_', f'derived.ratio_n{n}')}]"
                    lines.append(f"s_n{n} = {r} * q{c.index}")
                    lines.append(f"v_n{n} = {r} * w{c.index}")
                lines.append(f"F_n{n} = 0.0")
        return lines

    def _coordinate_lines(self) -> list[tuple[str, str]]:
        m = self.m
        lines: list[tuple[str, str]] = []
        for c in m.coordinates:
            terms: list[str] = []
            for n in c.nodes:
                f = f"F_n{n}"
                if n in self.node_scale:
                    f = f"{f} * {self.node_scale[n]}"
                if c.ratios[n] != "1.0":
                    f = f"{f} * p[{const_name('P_', f'derived.ratio_n{n}')}]"
                terms.append(f)
            inv = f"p[{const_name('P_', f'derived.inv_inertia.{c.name}')}]"
            lines.append(("dx", f"dx[{const_name('X_', c.position_state)}] = w{c.index}"))
            lines.append(
                ("dx", f"dx[{const_name('X_', c.velocity_state)}] = ({' + '.join(terms)}) * {inv}")
            )
            lines.append(
                (
                    "aux",
                    f"aux[{const_name('A_', f'stored.{c.name}.kinetic')}]"
                    f" = 0.5 * w{c.index} ** 2 / {inv}",
                )
            )
            lines.append(
                (
                    "aux",
                    f"aux[{const_name('A_', acceleration_name(c))}]"
                    f" = ({' + '.join(terms)}) * {inv}",
                )
            )
        return lines

    def _fill_derived(self) -> list[str]:
        m = self.m
        body: list[str] = []
        for c in m.coordinates:
            for n in c.nodes:
                expr = c.ratios[n]
                body.append(f"    p[{const_name('P_', f'derived.ratio_n{n}')}] = {expr}")
            terms: list[str] = []
            for n in c.nodes:
                for comp, slot, factor in m.inertia_nodes.get(n, ()):
                    r = f"p[{const_name('P_', f'derived.ratio_n{n}')}]"
                    terms.append(f"{factor!r} * p[{const_name('P_', f'{comp}.{slot}')}] * {r} ** 2")
            body.append(
                f"    p[{const_name('P_', f'derived.inv_inertia.{c.name}')}]"
                f" = 1.0 / ({' + '.join(terms)})"
            )
        return (
            ['@njit(cache=True, error_model="numpy")', "def fill_derived(p):"]
            + body
            + ["    return p"]
        )

    def module_source(self) -> str:
        # the import block ends at the first blank line: the kernel adds its own imports there
        head = [
            # no config path in the text: the same plant from another file reuses its kernel
            '"""Generated by feed_twin.plant.assembly; do not edit."""',
            "from numba import njit",
        ]
        if self.signal_names:
            head.append(f"from {SIGNALS} import {', '.join(sorted(self.signal_names))}")
        head += sorted(set(self.imports.values()))
        body_all = self._preamble()
        funcs: list[str] = []
        specs = (
            ("rhs", "t, x, p, out, ext, sw, dx", {"all", "dx"}),
            ("outputs", "t, x, p, out, ext, sw, aux", {"all", "aux"}),
            ("sense", "t, x, p, out, ext, sw, trig, noise, meas, mdelay", {"all", "meas"}),
        )
        coord_lines = self._coordinate_lines()
        for name, args, kinds in specs:
            lines = list(body_all)
            # sensors see positions, currents and the bus: `sense` skips the dynamics
            stages = SENSE_STAGES if name == "sense" else STAGES
            # coordinate sums go after `dynamics`/`transmit` lines; `sense` lines come last
            for kind, code, stage in self.lines:
                if kind == "angle" and stage in stages:
                    lines += self._angle_lines(name, int(code))
                elif kind in kinds and kind != "meas" and stage in stages:
                    lines.append(code)
            if name != "sense":
                lines += [code for kind, code in coord_lines if kind in kinds]
            lines += [code for kind, code, _ in self.lines if kind == "meas" and "meas" in kinds]
            lines = self._first_forces(lines)
            funcs.append("")
            # inlined into the loop: a call would pay numba's reference counting on every array
            # argument, several times the cost of the physics
            # numpy error model: a division by zero gives inf/NaN (caught by the divergence
            # check) instead of an exception, so unused calls are dead code LLVM can drop
            # no fast-math: reciprocals and fused products would change results in the last bits,
            # and with them depend on the CPU that compiled the kernel
            funcs.append('@njit(cache=True, inline="always", error_model="numpy")')
            funcs.append(f"def {name}({args}):")
            funcs += [f"    {code}" for code in lines]
            funcs.append("    return None")
            if name == "rhs":
                funcs += self._rhs_tuple(self._reexpand(lines, "rhs_tuple"), "rhs_tuple")
                # the first stage of a tick's first step is at the state `angles` saw: no rotation,
                # and LLVM finds the phase currents and their signs `sense` computed from it
                start = self._reexpand(lines, "rhs_tuple_start")
                funcs += self._rhs_tuple(start, "rhs_tuple_start")
        funcs += self._angles()
        funcs += self._draw_noise()
        return (
            "\n".join(head + [""] + self._constants() + [""] + self._fill_derived() + funcs) + "\n"
        )
