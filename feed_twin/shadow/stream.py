"""One time-stamped stream of a real machine (commands or measurements) on its slot grid.

The machine stamps every sample with its own cycle time; slot k is the sample stamped
`t0 + k * period`. Messages travel over a network and may arrive late, twice, out of order or
not at all. `SlotStream` turns what arrives into exactly one value per slot, in slot order, with
a bounded buffer and never waiting for ever. The policy, per message:

- on the grid: a stamp more than `tolerance * period` away from every slot is counted
  `off_grid` and dropped (a stamp that does not belong to the machine's cycle is not trusted);
- duplicated: a second sample for a slot still buffered, or for one released with a real value
  in the last `2 * window` slots, is dropped and counted `duplicated` (an older one is `late`);
- out of order: a sample older than the newest one received but for a slot not yet released is
  put in its place (the buffer is ordered by slot) and counted `reordered`;
- late: a sample for a slot already decided (the stream had run `window` slots past it, so it
  is, or will be, filled) is dropped and counted `late`; so is a sample from before the
  stream's start. Decisions depend only on the stream's own arrival order, never on when the
  twin calls `release`, so a replay in blocks decides exactly as the live twin did;
- far ahead: a sample more than `MAX_JUMP_S` ahead of the newest is dropped and counted
  `rejected` (a corrupted stamp must not make the twin simulate hours of filled samples);
- missing: once the stream has run `window` slots past a slot that never arrived, that slot is
  final: it is filled by linear interpolation between its released predecessor and its next
  received sample (`fill = "interpolate"`) or by holding the predecessor (`fill = "hold"`), and
  counted `missing`. At the start (no predecessor) the next sample is held backwards; a
  stream that never delivered anything is filled with NaN.
  `missing_run` counts the current run of consecutive missing slots;
- stopped: a stream that stops altogether cannot run past its missing slots, so the twin
  decides them from the other stream (`decide_through`, see ShadowTwin.silent_lead): they are
  filled (held) and counted `missing`.

Released values leave the buffer, so memory is bounded by `window` plus what arrives ahead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

MAX_JUMP_S = 60.0  # [s] a stamp this far beyond the newest one is rejected as corrupt


@dataclass
class FaultCounts:
    """How many messages of one stream met each rule of the policy (see the module docstring)."""

    received: int = 0
    accepted: int = 0  # buffered for a slot (includes reordered)
    reordered: int = 0
    duplicated: int = 0
    late: int = 0
    off_grid: int = 0
    rejected: int = 0
    missing: int = 0  # slots filled because their sample never came in time
    missing_run: int = 0  # consecutive filled slots up to the last released one

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class Released:
    """Values of consecutive slots `first .. first + len(values) - 1`, in slot order."""

    first: int
    values: np.ndarray  # (n, width)
    filled: np.ndarray  # (n,) bool: True where the policy filled a missing sample


class SlotStream:
    """Buffer one stream and release one value per slot (see the module docstring)."""

    def __init__(
        self,
        *,
        name: str,
        width: int,
        period_s: float,
        tolerance: float,
        window: int,
        fill: Literal["hold", "interpolate"],
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"{name}: period_s = {period_s!r}: must be > 0")
        if window < 1:
            raise ValueError(f"{name}: window = {window!r}: must be >= 1")
        if fill not in ("hold", "interpolate"):
            raise ValueError(f"{name}: fill = {fill!r}: must be 'hold' or 'interpolate'")
        self.name = name
        self.width = width
        self.period_s = float(period_s)
        self.tolerance = float(tolerance)
        self.window = int(window)
        self.fill = fill
        self.t0_s: float | None = None
        self.next_slot: int | None = None  # first slot not yet released (None before start)
        self.newest: int | None = None
        self.counts = FaultCounts()
        self._pending: dict[int, list[float]] = {}
        self._released_real: set[int] = set()  # recent real slots, for duplicate detection
        self._final_through = -(2**62)  # slots up to here are decided (filled if never seen)
        self._last: list[float] | None = None
        self._last_slot: int | None = None

    def set_origin(self, t0_s: float) -> None:
        """Put slot 0 at machine time t0_s (the twin shares one grid between its streams)."""
        self.t0_s = float(t0_s)

    def slot_of(self, t_s: float) -> tuple[int, bool]:
        if self.t0_s is None:
            raise RuntimeError(f"{self.name}: the slot grid has no origin yet")
        x = (t_s - self.t0_s) / self.period_s
        k = round(x)
        return k, abs(x - k) <= self.tolerance

    @property
    def pending_count(self) -> int:
        return len(self._pending)

    def first_pending(self) -> int | None:
        return min(self._pending) if self._pending else None

    def pending(self, slot: int) -> list[float] | None:
        """The values waiting in `slot`, None when nothing waits there."""
        return self._pending.get(slot)

    def push(self, t_s: float, values: np.ndarray | tuple | list) -> str:
        """Offer one sample; returns what the policy did with it (a FaultCounts field name)."""
        c = self.counts
        c.received += 1
        k, on_grid = self.slot_of(t_s)
        if not on_grid:
            c.off_grid += 1
            return "off_grid"
        if self.newest is not None and (k - self.newest) * self.period_s > MAX_JUMP_S:
            c.rejected += 1
            return "rejected"
        if k in self._pending or k in self._released_real:
            c.duplicated += 1
            return "duplicated"
        if (self.next_slot is not None and k < self.next_slot) or k <= self._final_through:
            c.late += 1
            return "late"
        self._pending[k] = [float(v) for v in values]
        c.accepted += 1
        if self.newest is not None and k < self.newest:
            c.reordered += 1
            return "reordered"
        self.newest = k
        self._final_through = k - self.window
        return "accepted"

    def push_many(self, t_s: np.ndarray, values: np.ndarray) -> None:
        """Offer samples in arrival order; the same policy as `push`, one sample at a time,
        with a vectorised path for the usual case (on the grid, each newer than the last)."""
        t_s = np.asarray(t_s, dtype=float)
        values = np.asarray(values, dtype=float).reshape(len(t_s), self.width)
        if len(t_s) == 0:
            return
        if self.t0_s is None:
            raise RuntimeError(f"{self.name}: the slot grid has no origin yet")
        x = (t_s - self.t0_s) / self.period_s
        k = np.round(x).astype(np.int64)
        lowest = max(self._final_through, -1 if self.newest is None else self.newest)
        clean = (
            bool(np.all(np.abs(x - k) <= self.tolerance))
            and bool(np.all(np.diff(k) > 0))
            and (self.newest is None or int(k[0]) > lowest)
            and (self.next_slot is None or int(k[0]) >= self.next_slot)
            and (self.newest is None or (int(k[-1]) - self.newest) * self.period_s <= MAX_JUMP_S)
            and (self.newest is not None or (int(k[-1]) - int(k[0])) * self.period_s <= MAX_JUMP_S)
        )
        if not clean:
            for t, row in zip(t_s, values, strict=True):
                self.push(float(t), row)
            return
        self._pending.update(zip(k.tolist(), values.tolist(), strict=True))
        n = len(k)
        self.counts.received += n
        self.counts.accepted += n
        self.newest = int(k[-1])
        self._final_through = self.newest - self.window

    def decide_through(self, slot: int) -> None:
        """Treat every slot up to `slot` as decided although this stream has not run past it
        (the twin calls this when the OTHER stream is far ahead: this one has stopped)."""
        if slot > self._final_through:
            self._final_through = int(slot)

    def start(self, slot: int) -> None:
        """Release from `slot` on; buffered samples before it are late."""
        self.next_slot = int(slot)
        for k in [k for k in self._pending if k < slot]:
            del self._pending[k]
            self.counts.late += 1
            self.counts.accepted -= 1

    def release(self, *, final: bool = False, limit: int | None = None) -> Released | None:
        """Every slot that is decided: received, or final because the stream ran `window` past
        it (with `final`, every slot up to the newest). At most `limit` slots."""
        if self.next_slot is None:
            return None
        newest = self.newest if self.newest is not None else self.next_slot - 1
        horizon = max(newest, self._final_through) if final else self._final_through
        k = self.next_slot
        # a stream decided from the other one (decide_through) fills beyond its newest slot
        last = max(newest, horizon)
        if limit is not None:
            last = min(last, k + limit - 1)
        if last < k:
            return None
        pending = self._pending
        # one comprehension over the candidate slots (a Python loop per slot costs 3x more)
        out = [pending.pop(s, None) for s in range(k, last + 1)]
        filled = [v is None for v in out]
        if True in filled:
            stop = next(
                (i for i, f in enumerate(filled) if f and k + i > horizon), len(out)
            )  # the first gap that is not decided yet ends this release
            for i in range(stop, len(out)):
                value = out[i]
                if value is not None:
                    pending[k + i] = value
            out, filled = out[:stop], filled[:stop]
            # each gap's next real sample within this release (popped already, so _filler
            # would not find it in the buffer)
            successor: list[tuple[int, list[float]] | None] = [None] * len(out)
            following: tuple[int, list[float]] | None = None
            for i in range(len(out) - 1, -1, -1):
                value = out[i]  # None where filled[i]
                if value is None:
                    successor[i] = following
                else:
                    following = (k + i, value)
            for i, f in enumerate(filled):
                if f:
                    if i:
                        self._last, self._last_slot = out[i - 1], k + i - 1
                    out[i] = self._filler(k + i, successor[i])
            self.counts.missing += sum(filled)
        if not out:
            return None
        n = len(out)
        real = [k + i for i, f in enumerate(filled) if not f]
        k += n
        self._last, self._last_slot = out[-1], k - 1
        # the current run of filled slots: those after the last real one of this release,
        # plus the run before it when nothing real was released
        trailing = n - (real[-1] - (k - n) + 1) if real else n
        self.counts.missing_run = trailing if real else self.counts.missing_run + trailing
        self._released_real.update(real[-2 * self.window :])
        if len(self._released_real) > 4 * self.window + 16:
            floor = k - 2 * self.window
            self._released_real = {s for s in self._released_real if s >= floor}
        first = self.next_slot
        self.next_slot = k
        return Released(first=first, values=np.array(out, dtype=float), filled=np.array(filled))

    def _filler(self, k: int, following: tuple[int, list[float]] | None) -> list[float]:
        """The value of missing slot k from its predecessor and the next real sample (given,
        or the nearest one still buffered)."""
        if following is None:
            ahead = [s for s in self._pending if s > k]
            if ahead:
                following = (min(ahead), self._pending[min(ahead)])
        if self._last is None:
            if following is None:
                return [math.nan] * self.width  # the stream never delivered anything
            return list(following[1])
        if self.fill == "hold" or following is None:
            return list(self._last)
        assert self._last_slot is not None
        nxt, value = following
        w = (k - self._last_slot) / (nxt - self._last_slot)
        return [(1.0 - w) * a + w * b for a, b in zip(self._last, value, strict=True)]
