"""The shadow twin: the integrated model driven, sample by sample, by a real machine's commands.

A real axis publishes its NC command (table position, optionally velocity) and its measurement
(position as its feedback sensor reports it, optionally the drive effort), each stamped with the
machine's own cycle time. `ShadowTwin` puts both streams on one slot grid (`SlotStream`, with the
documented message-fault policy), derives the feed-forward signals exactly as the discrepancy
workflow does, advances the engine over every slot whose command is decided, and pairs each
twin sample with the machine's measured sample of the same slot:

    fe_dev     = e_meas - e_twin = x_twin - x_meas          [m]
    effort_dev = effort_meas - effort_twin                  [effort unit: N, N m or A]

plus their RMS over the last `window_s` and the health verdicts of `HealthMonitor`.

Identity with the offline workflow (feed_twin.analysis.twin.Twin.simulate): the same compiled
twin (smooth sensors, the same sub-steps), the effort stamped as the machine's map says
(`effort_sample`: the command that acted up to the stamp, carried from one advance to the
next, or the one issued at it), the same start (at rest at the measured position of
the first slot), commands held over the slot's base ticks, the velocity (when the
machine sends none) and the acceleration from `numpy.gradient` over the command samples (central
differences inside, one-sided at both ends). Central differences need the next command sample,
so the twin runs one slot behind the command stream (two when it also derives the velocity).
Known disturbances (effort_add, external forces) of a recorded run are not part of a live
machine's streams and are not applied.

A stream that falls silent while the other goes on is decided from the other one: once that
is `silent_lead` slots ahead (SILENT_AFTER_S, at least missing_flag_after + reorder_window),
the silent stream's slots are filled and counted missing, so the twin never waits for ever and
its queues stay bounded; a measurement silent for missing_flag_after slots makes health STALE.

A divergence of the twin (NaN or runaway state) does not stop it: it is restarted at rest at the
measured position of the slot and counted in `twin_restarts`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from feed_twin.analysis.twin import Twin, acted
from feed_twin.io.column_map import EFFORT_SAMPLES
from feed_twin.shadow.config import ShadowConfig
from feed_twin.shadow.health import HealthMonitor, PhysicalEffect, Verdict
from feed_twin.shadow.stream import SlotStream
from feed_twin.sim.engine import DivergenceError
from feed_twin.sim.program import nc_reference

CMD_POS, CMD_VEL = 0, 1
SILENT_AFTER_S = 0.5  # [s] a stream this far behind the other one is decided as missing
MEAS_POS, MEAS_EFFORT = 0, 1


@dataclass(frozen=True, kw_only=True, eq=False)
class ResidualBlock:
    """Consecutive slots of paired machine and twin samples (SI; effort in its unit)."""

    t_s: np.ndarray  # machine time of each slot [s]
    x_cmd_m: np.ndarray
    x_meas_m: np.ndarray
    x_twin_m: np.ndarray
    effort_meas: np.ndarray  # NaN when the machine sends no effort
    effort_twin: np.ndarray
    fe_dev_m: np.ndarray
    effort_dev: np.ndarray
    fe_dev_rms_m: np.ndarray  # rolling RMS over window_s, up to and including the slot
    effort_dev_rms: np.ndarray
    measured_filled: np.ndarray  # bool: the machine's sample was missing and filled
    command_filled: np.ndarray  # bool

    def __len__(self) -> int:
        return len(self.t_s)

    @staticmethod
    def concat(blocks: list[ResidualBlock]) -> ResidualBlock:
        names = ResidualBlock.__dataclass_fields__
        return ResidualBlock(**{n: np.concatenate([getattr(b, n) for b in blocks]) for n in names})


class _RollingRms:
    """RMS of the last `size` values, per sample, across block boundaries.

    A running sum over a ring buffer costs O(1) a sample, which matters when the live twin
    calls this once per 1 ms slot; it is re-summed exactly once per `size` samples so that
    rounding does not accumulate. Long blocks (replay) go through cumulative sums.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.ring = np.zeros(size)
        self.pos = 0  # next write position
        self.count = 0  # values seen, up to size
        self.total = 0.0
        self._since_resum = 0

    def __call__(self, values: np.ndarray) -> np.ndarray:
        sq = np.square(np.asarray(values, dtype=float))
        n = len(sq)
        if n > 64:
            tail = self._ordered()
            all_sq = np.concatenate([tail, sq])
            cs = np.concatenate(([0.0], np.cumsum(all_sq)))
            end = np.arange(len(tail) + 1, len(all_sq) + 1)
            begin = np.maximum(end - self.size, 0)
            out = np.sqrt(np.maximum((cs[end] - cs[begin]) / (end - begin), 0.0))
            keep = all_sq[-self.size :]
            self.ring[: len(keep)] = keep
            self.count = len(keep)
            self.pos = len(keep) % self.size
            self.total = float(np.sum(keep))
            self._since_resum = 0
            return out
        out = np.empty(n)
        ring, size = self.ring, self.size
        for i, v in enumerate(sq.tolist()):
            self.total += v - ring[self.pos]
            ring[self.pos] = v
            self.pos = (self.pos + 1) % size
            self.count = min(self.count + 1, size)
            self._since_resum += 1
            if self._since_resum >= size:
                self.total = float(np.sum(ring[: self.count]))
                self._since_resum = 0
            out[i] = math.sqrt(max(self.total / self.count, 0.0))
        return out

    def _ordered(self) -> np.ndarray:
        if self.count < self.size:
            return self.ring[: self.count].copy()
        return np.concatenate([self.ring[self.pos :], self.ring[: self.pos]])


def _finite_or_zero(a: np.ndarray) -> np.ndarray:
    return a if np.isfinite(a).all() else np.where(np.isfinite(a), a, 0.0)


class _Rows:
    """A SimResult seen as a batch of one, for Twin's signal extraction."""

    def __init__(self, res: Any) -> None:
        self.names = res.names
        self._res = res

    def __getitem__(self, name: str) -> np.ndarray:
        return self._res[name][None, :]


def physical_effects(twin: Twin) -> tuple[PhysicalEffect, ...]:
    """The library effects whose weight maps to a parameter of this model, with their scales:
    a friction resists every motion, the screw drives it; inertia and a constant force are
    driven against as often as they drive (analysis.model_doc.ModelDoc.force_per_effort)."""
    doc = twin.doc
    per_effort = doc.force_per_effort(twin.effort_unit, resisting=True)
    per_effort_both = doc.force_per_effort(twin.effort_unit, resisting=False)
    if per_effort is None or per_effort_both is None:
        return ()
    out: list[PhysicalEffect] = []
    friction = doc.friction()
    if friction is not None:
        p = doc.component(friction)["params"]
        for effect, reg, field, unit in (
            ("coulomb_friction", "sign_v", "F_c", "N"),
            ("viscous_friction", "v", "F_v", "N s/m"),
        ):
            nominal = 0.5 * (float(p[f"{field}_pos"]) + float(p[f"{field}_neg"]))
            out.append(
                PhysicalEffect(
                    effect=effect,
                    regressor=reg,
                    parameter=f"plant.{friction}.{field}",
                    unit=unit,
                    nominal=nominal,
                    per_effort=per_effort,
                )
            )
    mass = doc.mass_slot()
    if mass is not None:
        out.append(
            PhysicalEffect(
                effect="mass_error",
                regressor="a",
                parameter=f"plant.{mass}",
                unit="kg",
                nominal=doc.get(mass),
                per_effort=per_effort_both,
            )
        )
    forces = doc.of_type("ConstantForce")
    # ConstantForce pushes the table in +x; the drive must supply the opposite effort
    nominal_f0 = doc.get(f"{forces[0]}.f_0") if forces else 0.0
    out.append(
        PhysicalEffect(
            effect="constant_force",
            regressor="one",
            parameter=f"plant.{forces[0]}.f_0" if forces else "plant.constant_force.f_0",
            unit="N",
            nominal=nominal_f0,
            per_effort=-per_effort_both,
        )
    )
    return tuple(out)


class ShadowTwin:
    """Run `twin` in step with a machine's command and measured streams (module docstring)."""

    def __init__(
        self,
        twin: Twin,
        config: ShadowConfig,
        *,
        command_velocity: bool,
        travel_m: float,
        effort_sample: Literal["actual", "setpoint"],
        measured_effort: bool = True,
    ) -> None:
        if effort_sample not in EFFORT_SAMPLES:
            raise ValueError(
                f"effort_sample = {effort_sample!r}: must be one of {', '.join(EFFORT_SAMPLES)}"
            )
        self.twin = twin
        # the machine's effort at a stamp is the one that acted up to it (the twin's command
        # of the base tick before, or a current its model integrates as it stands at the stamp:
        # Twin.effort_is_current) or the command issued at it (ColumnMap.effort_sample)
        self.effort_actual = effort_sample == "actual" and not twin.effort_is_current
        self._effort_before: np.ndarray | None = None  # the last base tick's command
        self.config = config
        self.engine = twin.engine
        h = config.sample_period_s
        self.dec = round(h / self.engine.h)
        if self.dec < 1 or abs(self.dec * self.engine.h - h) > 1e-9 * h:
            raise ValueError(
                f"shadow.sample_period_s = {h!r}: must be a whole multiple of the model's base "
                f"period {self.engine.h!r} s"
            )
        self.command_velocity = bool(command_velocity)
        self.lookahead = 1 if self.command_velocity else 2

        def stream(name: str, width: int) -> SlotStream:
            return SlotStream(
                name=name,
                width=width,
                period_s=h,
                tolerance=config.stamp_tolerance,
                window=config.reorder_window,
                fill=config.missing_fill,
            )

        self.commands = stream("command", 2 if command_velocity else 1)
        self.measured = stream("measured", 2)
        self.health = HealthMonitor(
            config,
            physical=physical_effects(twin),
            effort_unit=twin.effort_unit,
            lead_m=twin.lead_m,
            pole_pairs=twin.pole_pairs,
            travel_m=travel_m,
            has_effort=measured_effort,
        )
        self.start_slot: int | None = None
        # slots one stream may be ahead before the other counts as silent: at least the
        # missing-sample flag, and SILENT_AFTER_S, because a busy node's executor may serve
        # one subscription's backlog well before the other's
        self.silent_lead = max(
            config.missing_flag_after + config.reorder_window, round(SILENT_AFTER_S / h)
        )
        self.twin_restarts = 0
        self.last_restart_message = ""
        self._fe_rms = _RollingRms(config.window_samples)
        self._eff_rms = _RollingRms(config.window_samples)
        self._engine_started = False
        # released command rows not yet simulated, plus the two before them (for differences)
        self._cmd_first = 0  # slot of _cmd[0]
        self._cmd = np.zeros((0, 2))
        self._cmd_filled = np.zeros(0, dtype=bool)
        self._next_sim: int | None = None
        self._twin_q: list[np.ndarray] = []  # rows: slot, x_cmd, x_twin, effort_twin, filled
        self._meas_q: list[np.ndarray] = []  # rows: slot, x_meas, effort_meas, filled
        self.new_verdicts: list[Verdict] = []

    def set_origin(self, t_s: float) -> None:
        """Put slot 0 of both streams at machine time t_s (the first stamp seen, by default)."""
        if self.commands.t0_s is None:
            self.commands.set_origin(t_s)
            self.measured.set_origin(t_s)

    def push_command(self, t_s: float, pos_m: float, vel_m_s: float | None = None) -> str:
        """One NC sample of the machine; returns the policy's outcome (FaultCounts field)."""
        self.set_origin(t_s)
        if self.command_velocity:
            if vel_m_s is None:
                raise ValueError("push_command: this twin takes the command velocity; none given")
            return self.commands.push(t_s, (pos_m, vel_m_s))
        return self.commands.push(t_s, (pos_m,))

    def push_measured(self, t_s: float, pos_m: float, effort: float = math.nan) -> str:
        """One measured sample: position [m] as the feedback sensor reports it, drive effort."""
        self.set_origin(t_s)
        return self.measured.push(t_s, (pos_m, effort))

    def push_commands(
        self, t_s: np.ndarray, pos_m: np.ndarray, vel_m_s: np.ndarray | None = None
    ) -> None:
        """Several NC samples in arrival order (the same policy as push_command)."""
        if len(t_s) == 0:
            return
        self.set_origin(float(t_s[0]))
        if self.command_velocity:
            if vel_m_s is None:
                raise ValueError("push_commands: this twin takes the command velocity; none given")
            self.commands.push_many(t_s, np.column_stack([pos_m, vel_m_s]))
        else:
            self.commands.push_many(t_s, np.asarray(pos_m, dtype=float)[:, None])

    def push_measured_many(
        self, t_s: np.ndarray, pos_m: np.ndarray, effort: np.ndarray | None = None
    ) -> None:
        """Several measured samples in arrival order (the same policy as push_measured)."""
        if len(t_s) == 0:
            return
        self.set_origin(float(t_s[0]))
        eff = np.full(len(t_s), math.nan) if effort is None else np.asarray(effort, dtype=float)
        self.measured.push_many(t_s, np.column_stack([pos_m, eff]))

    def process(self, *, final: bool = False) -> ResidualBlock | None:
        """Advance over every decided slot; the newly paired samples (None if there are none).

        `final`: the streams have ended; every slot up to the newest is decided now.
        """
        self.new_verdicts = []
        if self.start_slot is None and not self._try_start(final):
            return None
        # a stream that went silent is decided from the other one (see SlotStream), so neither
        # the twin nor the pairing waits for it and the queues stay bounded
        lead = self.silent_lead
        if self.commands.newest is not None:
            self.measured.decide_through(self.commands.newest - lead)
        if self.measured.newest is not None:
            self.commands.decide_through(self.measured.newest - lead)
        m = self.measured.release(final=final)
        if m is not None:
            n = len(m.values)
            self._meas_q.append(
                np.column_stack(
                    [np.arange(m.first, m.first + n), m.values[:, 0], m.values[:, 1], m.filled]
                )
            )
        if not self._engine_started:
            if not self._meas_q:
                return None
            x0 = float(self._meas_q[0][0, 1])
            if not math.isfinite(x0):
                # no measurement at the start (a silent stream): start where the NC commands
                assert self.start_slot is not None  # set by _try_start above
                start_cmd = self.commands.pending(self.start_slot)
                x0 = float(start_cmd[CMD_POS]) if start_cmd is not None else 0.0
            self._restart(x0)
            self._engine_started = True
        c = self.commands.release(final=final)
        if c is not None:
            rows = c.values if self.command_velocity else np.column_stack([c.values, c.values])
            self._cmd = np.concatenate([self._cmd, rows])
            self._cmd_filled = np.concatenate([self._cmd_filled, c.filled])
        self._simulate(final)
        return self._pair()

    def _try_start(self, final: bool) -> bool:
        first = self.commands.first_pending()
        if first is None or self.commands.newest is None:
            return False
        if self.commands.newest < first + self.lookahead and not final:
            return False
        self.start_slot = first
        self.commands.start(first)
        self.measured.start(first)
        self._cmd_first = first
        self._next_sim = first
        return True

    def _restart(self, x0_m: float) -> None:
        self.engine.reset(x0=self.twin.initial_state(x0_m, self.engine.p))
        self._effort_before = None

    def _derived(self, final: bool) -> tuple[np.ndarray, np.ndarray] | None:
        """(rows [pos, vel, acc], filled) of the slots whose derivatives are decided."""
        assert self._next_sim is not None and self.start_slot is not None
        n_have = len(self._cmd)
        last_have = self._cmd_first + n_have - 1
        last_ready = last_have if final else last_have - self.lookahead
        if last_ready < self._next_sim or n_have == 0:
            return None
        h = self.config.sample_period_s
        pos = self._cmd[:, CMD_POS]
        if self.command_velocity:
            vel = self._cmd[:, CMD_VEL]
        else:
            vel = np.gradient(pos, h) if n_have > 1 else np.zeros(1)
            # the buffer's first entry is one-sided unless it is the run's first slot: it is
            # only used for slots two or more behind, whose value is already simulated
        acc = np.gradient(vel, h) if n_have > 1 else np.zeros(1)
        i0 = self._next_sim - self._cmd_first
        i1 = last_ready - self._cmd_first + 1
        rows = np.column_stack([pos[i0:i1], vel[i0:i1], acc[i0:i1]])
        return rows, self._cmd_filled[i0:i1]

    def _simulate(self, final: bool) -> None:
        derived = self._derived(final)
        if derived is None:
            return
        rows, filled = derived
        n = len(rows)
        ref = nc_reference(rows[:, 0], rows[:, 1], rows[:, 2], self.dec)
        assert self._next_sim is not None
        slots = np.arange(self._next_sim, self._next_sim + n)
        try:
            res = self.engine.advance(n * self.dec, ref=ref)
            x, eff = self.twin.measured_signals(_Rows(res), 1)  # every base tick
            if self.effort_actual:
                issued = eff
                eff = acted(issued, self._effort_before)
                self._effort_before = issued[:, -1:]
            x_twin, eff_twin = x[0, :: self.dec], eff[0, :: self.dec]
        except DivergenceError as exc:
            self.twin_restarts += 1
            self.last_restart_message = str(exc)
            x_twin = np.full(n, np.nan)
            eff_twin = np.full(n, np.nan)
            self._restart_at(slots[-1])
        self._twin_q.append(np.column_stack([slots, rows[:, 0], x_twin, eff_twin, filled]))
        self._next_sim += n
        # keep the two slots before the next one: central differences reach back that far
        keep_from = max(self._next_sim - 2, self.start_slot or 0) - self._cmd_first
        if keep_from > 0:
            self._cmd = self._cmd[keep_from:]
            self._cmd_filled = self._cmd_filled[keep_from:]
            self._cmd_first += keep_from

    def _restart_at(self, slot: int) -> None:
        x0 = None
        for block in reversed(self._meas_q):
            hit = block[block[:, 0] <= slot]
            if len(hit):
                x0 = float(hit[-1, 1])
                break
        self._restart(x0 if x0 is not None else 0.0)

    def _pair(self) -> ResidualBlock | None:
        if not self._twin_q or not self._meas_q:
            return None
        tw = np.concatenate(self._twin_q)
        me = np.concatenate(self._meas_q)
        n = min(len(tw), len(me))
        if n == 0:
            return None
        self._twin_q = [tw[n:]] if len(tw) > n else []
        self._meas_q = [me[n:]] if len(me) > n else []
        tw, me = tw[:n], me[:n]
        assert np.array_equal(tw[:, 0], me[:, 0])  # both queues run in slot order from start
        assert self.commands.t0_s is not None  # samples exist only once the origin is set
        t = self.commands.t0_s + tw[:, 0] * self.config.sample_period_s
        fe_dev = tw[:, 2] - me[:, 1]
        effort_dev = me[:, 2] - tw[:, 3]
        block = ResidualBlock(
            t_s=t,
            x_cmd_m=tw[:, 1],
            x_meas_m=me[:, 1],
            x_twin_m=tw[:, 2],
            effort_meas=me[:, 2],
            effort_twin=tw[:, 3],
            fe_dev_m=fe_dev,
            effort_dev=effort_dev,
            fe_dev_rms_m=self._fe_rms(_finite_or_zero(fe_dev)),
            effort_dev_rms=self._eff_rms(_finite_or_zero(effort_dev)),
            measured_filled=me[:, 3].astype(bool),
            command_filled=tw[:, 4].astype(bool),
        )
        # filled measured samples and twin restarts are not evidence about the machine
        valid = np.isfinite(fe_dev) & ~block.measured_filled
        health_rows = np.column_stack(
            [t, me[:, 1], fe_dev, _finite_or_zero(effort_dev), _finite_or_zero(tw[:, 3])]
        )
        self.new_verdicts = self.health.update(health_rows, valid=valid)
        return block

    def counts(self) -> dict[str, Any]:
        return {
            "command": self.commands.counts.as_dict(),
            "measured": self.measured.counts.as_dict(),
            "twin_restarts": self.twin_restarts,
        }
