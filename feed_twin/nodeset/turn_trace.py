"""A per-turn timing trace of a node's loop: what stops it, found by measurement.

With `FEED_TWIN_TURN_TRACE=DIR` in its environment, a node process (feed_twin.ros.runtime's
spin loop) writes `DIR/<role>_<pid>.npz` at its end:

- one row per turn of its loop (`turn()`): the wall time [ns, monotonic] and, from the
  kernel's scheduler statistics of the loop's thread (`/proc/thread-self/schedstat`), how long
  that thread had run on a CPU and how long it had waited on a run queue for one (runnable, not
  running: starvation by other processes), both cumulative [ns];
- one row per span the node marks (`span(kind, value)`: a callback, a step of the twin, a
  publish) with its start, end and a number the kind gives meaning to (messages, slots, the age
  of a batch [us]); its start and end are signs of life of the thread, recorded as the turns
  are (with the scheduler's figures);
- one span per garbage collection (`gc.callbacks`), kind `gc<generation>`;
- the datagrams the kernel dropped on the process's UDP sockets by its end (`udp_drops`).

`LoadedTrace.summary` splits the time between two turns (`turn_gap`: the loop did not come
back) and between two signs of life (`activity_gap`: the thread did nothing it marks) into CPU,
run-queue wait, the marked spans by kind, the collections and the rest: off the CPU without
waiting for it, i.e. blocked (a lock, the GIL, a socket) or idle with nothing to do. The
largest gaps name the cause of a stall.

Pure (no rclpy); reading the thread's schedstat costs about 4 us, twice a span, so the trace is
for diagnosis only (benchmarks/twin_loop_gaps.py).
"""

from __future__ import annotations

import contextlib
import gc
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TRACE_ENV = "FEED_TWIN_TURN_TRACE"
SCHEDSTAT = "/proc/thread-self/schedstat"


class TurnTrace:
    """Records turns and spans of the thread that creates it (module docstring)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        # opened by the loop's thread: /proc/thread-self resolves to it at open time
        self._stat = open(SCHEDSTAT, "rb", buffering=0)  # noqa: SIM115 - closed in write()
        # wall time, run and run-queue time, 1 for a loop turn (0: another sign of life)
        self.turns: list[tuple[int, int, int, int]] = []
        self.spans: list[tuple[int, int, int, int]] = []
        self.kinds: dict[str, int] = {}
        self._gc_start = 0
        gc.callbacks.append(self._on_gc)

    def _sched(self) -> tuple[int, int]:
        self._stat.seek(0)
        run_ns, wait_ns, _ = self._stat.read(96).split()
        return int(run_ns), int(wait_ns)

    def turn(self) -> None:
        """One turn of the loop begins."""
        self.turns.append((time.monotonic_ns(), *self._sched(), 1))

    def _alive(self, t_ns: int) -> None:
        """A sign of life of the thread that is not a turn (a span's start or end)."""
        self.turns.append((t_ns, *self._sched(), 0))

    def _kind(self, kind: str) -> int:
        return self.kinds.setdefault(kind, len(self.kinds))

    def add(self, kind: str, start_ns: int, end_ns: int, value: int = 0) -> None:
        self.spans.append((start_ns, end_ns, self._kind(kind), value))
        self._alive(end_ns)

    @contextlib.contextmanager
    def span(self, kind: str, value: int = 0) -> Iterator[None]:
        start = time.monotonic_ns()
        self._alive(start)
        try:
            yield
        finally:
            self.add(kind, start, time.monotonic_ns(), value)

    def _on_gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._gc_start = time.monotonic_ns()
            self._alive(self._gc_start)
        else:
            self.add(f"gc{info['generation']}", self._gc_start, time.monotonic_ns(),
                     int(info.get("collected", 0)))  # fmt: skip

    def write(self) -> Path:
        """Save the trace (npz) and stop recording collections."""
        with contextlib.suppress(ValueError):
            gc.callbacks.remove(self._on_gc)
        self._stat.close()
        names = sorted(self.kinds, key=self.kinds.__getitem__)
        np.savez(
            self.path,
            udp_drops=np.asarray(udp_drops(), dtype=np.int64),
            turns=np.asarray(self.turns, dtype=np.int64).reshape(-1, 4),
            spans=np.asarray(self.spans, dtype=np.int64).reshape(-1, 4),
            kinds=np.asarray(names, dtype=str),
        )
        return self.path


def udp_drops(proc: Path = Path("/proc")) -> int:
    """Datagrams the kernel dropped on this process's UDP sockets (their receive buffer was
    full: the reader did not take them in time), from /proc/net/udp's `drops` column."""
    fds = proc / "self" / "fd"
    inodes = set()
    for fd in os.listdir(fds):
        with contextlib.suppress(OSError):
            target = os.readlink(fds / fd)
            if target.startswith("socket:["):
                inodes.add(target[len("socket:[") : -1])
    dropped = 0
    for table in ("udp", "udp6"):
        with contextlib.suppress(OSError), open(proc / "net" / table) as f:
            next(f)  # the header
            for line in f:
                fields = line.split()
                if fields[9] in inodes:  # inode, then ref, pointer, drops
                    dropped += int(fields[12])
    return dropped


class NoTrace:
    """What a node records into when no trace is asked for: nothing, at no cost."""

    def turn(self) -> None:
        pass

    def add(self, kind: str, start_ns: int, end_ns: int, value: int = 0) -> None:
        pass

    def span(self, kind: str, value: int = 0) -> contextlib.AbstractContextManager[None]:
        return contextlib.nullcontext()

    def write(self) -> None:
        return None


NO_TRACE = NoTrace()


def trace_from_environ(role: str, environ: dict[str, str] | None = None) -> TurnTrace | NoTrace:
    """A TurnTrace writing to `$FEED_TWIN_TURN_TRACE/<role>_<pid>.npz`, or NO_TRACE."""
    directory = (os.environ if environ is None else environ).get(TRACE_ENV)
    if not directory:
        return NO_TRACE
    path = Path(directory)
    if not path.is_dir():
        raise ValueError(f"{TRACE_ENV} = {directory!r}: not a directory")
    return TurnTrace(path / f"{role}_{os.getpid()}.npz")


@dataclass(frozen=True, kw_only=True)
class Gap:
    """The time between two turns of a node's loop, split by where it went [s]."""

    start_s: float  # [s] from the first turn
    wall_s: float
    cpu_s: float  # the loop's thread on a CPU
    runqueue_s: float  # runnable, waiting for a CPU (other processes had them)
    spans_s: dict[str, float]  # marked spans by kind (their CPU and waits included)
    off_cpu_s: float  # neither running nor runnable: blocked or idle

    def as_dict(self) -> dict:
        return {
            "start_s": round(self.start_s, 3),
            "wall_ms": round(self.wall_s * 1e3, 2),
            "cpu_ms": round(self.cpu_s * 1e3, 2),
            "runqueue_ms": round(self.runqueue_s * 1e3, 2),
            "off_cpu_ms": round(self.off_cpu_s * 1e3, 2),
            "spans_ms": {k: round(v * 1e3, 2) for k, v in self.spans_s.items() if v > 0.0},
        }


@dataclass(frozen=True, kw_only=True)
class LoadedTrace:
    marks: np.ndarray  # (n, 4) int64 in time order: wall, run, run-queue wait [ns], loop turn
    spans: np.ndarray  # (m, 4) int64: start, end, kind, value
    kinds: tuple[str, ...]
    udp_drops: int  # datagrams dropped on the process's sockets by its end (udp_drops)

    @classmethod
    def load(cls, path: Path) -> LoadedTrace:
        with np.load(path) as f:
            marks = f["turns"]
            return cls(marks=marks[np.argsort(marks[:, 0], kind="stable")], spans=f["spans"],
                       kinds=tuple(str(k) for k in f["kinds"]),
                       udp_drops=int(f["udp_drops"]))  # fmt: skip

    def gap(self, first: np.ndarray, second: np.ndarray) -> Gap:
        """From mark `first` to mark `second` (rows of `marks`)."""
        (t0, run0, wait0, _), (t1, run1, wait1, _) = first.tolist(), second.tolist()
        s = self.spans
        inside = s[(s[:, 1] > t0) & (s[:, 0] < t1)]
        by_kind: dict[str, float] = {}
        for start, end, kind, _ in inside.tolist():
            name = self.kinds[kind]
            by_kind[name] = by_kind.get(name, 0.0) + (min(end, t1) - max(start, t0)) * 1e-9
        wall, cpu, waited = (t1 - t0) * 1e-9, (run1 - run0) * 1e-9, (wait1 - wait0) * 1e-9
        return Gap(
            start_s=(t0 - self.marks[0, 0]) * 1e-9,
            wall_s=wall,
            cpu_s=cpu,
            runqueue_s=waited,
            spans_s=by_kind,
            off_cpu_s=max(0.0, wall - cpu - waited),
        )

    def summary(self, *, top: int = 5) -> dict:
        """The gaps between loop turns and between any two signs of life of the loop's thread
        (a turn, the end of a span: `activity_gap`), p50/p99/max [ms] each, with the `top`
        largest split by cause; the share of wall time on a CPU and on a run queue; the
        marked spans by kind (durations and values)."""
        m = self.marks
        if len(m) < 2:
            return {"marks": len(m)}
        wall = (m[-1, 0] - m[0, 0]) * 1e-9
        spans = self.spans
        durations = (spans[:, 1] - spans[:, 0]) * 1e-9
        kinds = {}
        for k, name in enumerate(self.kinds):
            of_kind = spans[:, 2] == k
            d, values = durations[of_kind], spans[of_kind, 3]
            if d.size:
                kinds[name] = {"count": int(d.size), "total_s": round(float(d.sum()), 3),
                               "p99_ms": round(float(np.percentile(d, 99)) * 1e3, 2),
                               "max_ms": round(float(d.max()) * 1e3, 2),
                               "value_p50": float(np.percentile(values, 50)),
                               "value_p99": float(np.percentile(values, 99)),
                               "value_max": int(values.max())}  # fmt: skip
        return {
            "wall_s": round(wall, 2),
            "cpu_share": round((m[-1, 1] - m[0, 1]) * 1e-9 / wall, 3),
            "runqueue_share": round((m[-1, 2] - m[0, 2]) * 1e-9 / wall, 3),
            "udp_drops": self.udp_drops,
            "turn_gap": self._gaps(m[m[:, 3] == 1], top),
            "activity_gap": self._gaps(m, top),
            "spans": kinds,
        }

    def _gaps(self, marks: np.ndarray, top: int) -> dict:
        gaps = np.diff(marks[:, 0]) * 1e-9
        if gaps.size == 0:
            return {"count": 0}
        largest = np.argsort(gaps)[::-1][:top]
        return {
            "count": int(gaps.size),
            "p50_ms": round(float(np.percentile(gaps, 50)) * 1e3, 2),
            "p99_ms": round(float(np.percentile(gaps, 99)) * 1e3, 2),
            "max_ms": round(float(gaps.max()) * 1e3, 2),
            "over_100ms": int(np.count_nonzero(gaps > 0.1)),
            "largest": [self.gap(marks[i], marks[i + 1]).as_dict() for i in largest.tolist()],
        }
