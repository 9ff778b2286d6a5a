"""Batch mode: N parameter sets of one engine's model advanced side by side.

    result = run_batch(engine, P, n_ticks, ref=ref)   # P: (N, len(model.param_names))
    result["table.s"]                                  # (N, recorded samples)

Every set starts from the engine's initial state (or `x0`) and a fresh controller, shares the
inputs, and runs in the compiled loop that reads its parameters (`Engine.kernel_for` its
controller structure, also for an engine that inlines its own values) on one thread per usable
core; the kernel releases the GIL. Sets whose
regularised friction is too sharp for the step are refused before anything runs (`check_steps`,
the same verdicts and messages as `check_step` set by set); a set that diverges is marked and the
others run on.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from types import ModuleType
from typing import NamedTuple

import numpy as np

from feed_twin.control.layout import STRUCTURE_SLOTS
from feed_twin.core import signals
from feed_twin.plant.assembly import PlantModel
from feed_twin.sim.engine import (
    RK4_STABILITY_MARGIN,
    Engine,
    check_step,
    divergence_message,
)
from feed_twin.sim.kernel import RING


def check_steps(model: PlantModel, P: np.ndarray, h: float, nsub: int) -> list[str]:
    """`check_step` for every row of P: "" for a row that may run, else its error message.

    The damping slopes are evaluated once per distinct value of the slots each component reads
    and the stability ratios for all rows at once (the same floating-point operations as
    `check_step`, so the same verdicts); only refused rows go through `check_step` itself, for
    its message: a per-row Python loop would be a noticeable part of a batch.
    """
    hs = h / nsub
    refused = np.zeros(len(P), dtype=bool)
    for name, comp in model.components.items():
        read: list[str] = []

        def probe(field: str, name: str = name, read: list[str] = read) -> float:
            if field not in read:
                read.append(field)
            return float(P[0, model.param_index[f"{name}.{field}"]])

        if len(P) == 0:
            break
        comp.damping_bounds(probe)
        if read:
            cols = [model.param_index[f"{name}.{f}"] for f in read]
            groups, which = np.unique(P[:, cols], axis=0, return_inverse=True)
        else:
            groups, which = np.zeros((1, 0)), np.zeros(len(P), dtype=np.int64)
        for g, values in enumerate(groups):
            known = dict(zip(read, values.tolist(), strict=True))
            try:
                bounds = comp.damping_bounds(lambda f, known=known: known[f])
            except KeyError:  # this group's values take another branch: check its rows one by one
                rows = np.flatnonzero(which.ravel() == g)
                for b in rows:
                    try:
                        check_step(model, P[b], h, nsub)
                    except ValueError:
                        refused[b] = True
                continue
            mine = which.ravel() == g
            for port, c in bounds.items():
                node = model.node_of[f"{name}.{port}"]
                coord = model.coordinates[model.coordinate_of[node]]
                r = P[:, model.param_index[f"derived.ratio_n{node}"]]
                inv = P[:, model.param_index[f"derived.inv_inertia.{coord.name}"]]
                rate = hs * c * r * r * inv
                refused |= mine & (rate >= RK4_STABILITY_MARGIN)
        refused |= _fast_states(model, name, P, hs)
    messages = [""] * len(P)
    for b in np.flatnonzero(refused):
        try:
            check_step(model, P[b], h, nsub)
        except ValueError as exc:
            messages[b] = str(exc)
    return messages


def _fast_states(model: PlantModel, name: str, P: np.ndarray, hs: float) -> np.ndarray:
    """The rows of P whose step is too long for the component's own states
    (Component.state_rate), evaluated once per distinct value of the slots it reads."""
    comp = model.components[name]
    read: list[str] = []

    def probe(field: str) -> float:
        if field not in read:
            read.append(field)
        return float(P[0, model.param_index[f"{name}.{field}"]])

    if len(P) == 0 or (comp.state_rate(probe) == 0.0 and not read):
        return np.zeros(len(P), dtype=bool)
    cols = [model.param_index[f"{name}.{f}"] for f in read]
    groups, which = np.unique(P[:, cols], axis=0, return_inverse=True)
    too_fast = np.zeros(len(groups), dtype=bool)
    for i, values in enumerate(groups):
        known = dict(zip(read, values.tolist(), strict=True))
        too_fast[i] = hs * comp.state_rate(known.__getitem__) >= RK4_STABILITY_MARGIN
    return too_fast[which.ravel()]


BLOCKS_PER_THREAD = 16  # blocks of sets a batch thread takes from the queue, on average
SHARED_NORMALS_BYTES = 64 * 2**20  # memory for noise tables that sets of one seed share


def default_threads() -> int:
    """Threads of the batch mode: the cores this process may use."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:
        return os.cpu_count() or 1


@dataclass(frozen=True)
class BatchResult:
    """Signals of N parameter sets: data (N, T, signals); `status[b]` is 0 or the diverged tick."""

    t: np.ndarray
    names: tuple[str, ...]
    data: np.ndarray
    diverged: np.ndarray  # bool (N,)
    messages: tuple[str, ...]  # one per set, "" when the set ran through

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.data[:, :, self.names.index(name)]
        except ValueError:
            raise KeyError(
                f"signal {name!r}: not recorded; signals: {', '.join(self.names)}"
            ) from None


class _Sets(NamedTuple):
    """The per-set arrays of a batch (one row per set)."""

    X: np.ndarray
    P: np.ndarray
    CP: np.ndarray
    CS: np.ndarray
    seeds: np.ndarray
    table_of: np.ndarray  # row of the shared noise tables the set reads, or -1: it draws
    rings: np.ndarray
    outs: np.ndarray
    rec: np.ndarray
    status: np.ndarray
    works: np.ndarray

    def take(self, rows: np.ndarray) -> _Sets:
        return _Sets(*(a[rows] for a in self))  # copies (fancy indexing)


def _structures(engine: Engine, CP: np.ndarray) -> list[np.ndarray]:
    """The rows of each controller structure among the sets (usually one group of all):
    each runs on the kernel compiled for it (`Engine.kernel_for`)."""
    if engine.controller is None:
        return [np.arange(len(CP))]
    keys = CP[:, list(STRUCTURE_SLOTS)]
    _, which = np.unique(keys, axis=0, return_inverse=True)
    which = which.ravel()
    return [np.flatnonzero(which == g) for g in range(which.max(initial=-1) + 1)]


def _shared_normals(
    kernel: ModuleType, seeds: np.ndarray, n_ticks: int
) -> tuple[np.ndarray, np.ndarray]:
    """(tables, table_of): the standard normal samples of n_ticks ticks, drawn once for each seed
    that several sets share (within SHARED_NORMALS_BYTES, the most shared seeds first), and per
    set the table it reads (-1: the set draws its own, as a single run does).

    A sample depends on (seed, tick, channel) alone, so the sets get the same doubles either
    way; drawn in the loop, every set would pay for the same draws again.
    """
    n_noise = kernel.N_NOISE
    table_of = np.full(len(seeds), -1, dtype=np.int64)
    if n_noise == 0 or n_ticks == 0:
        return np.zeros((1, 0, n_noise)), table_of
    values, which, counts = np.unique(seeds, return_inverse=True, return_counts=True)
    which = which.ravel()
    room = SHARED_NORMALS_BYTES // (n_ticks * n_noise * 8)
    shared = [g for g in np.argsort(-counts, kind="stable") if counts[g] >= 2][:room]
    if not shared:
        return np.zeros((1, 0, n_noise)), table_of
    tables = np.empty((len(shared), n_ticks, n_noise))
    for t, g in enumerate(shared):
        kernel.standard_normals(int(values[g]), 0, n_ticks, tables[t])
        table_of[which == g] = t
    return tables, table_of


def _advance_blocks(
    kernel: ModuleType,
    engine: Engine,
    n_ticks: int,
    inputs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    sets: _Sets,
    n_threads: int,
) -> None:
    """Advance the sets from tick 0 on `kernel`: `n_threads` threads take contiguous blocks of
    sets from a queue, BLOCKS_PER_THREAD blocks per thread."""
    X, P, CP, CS, seeds, table_of, rings, outs, rec, status, works = sets
    ref, drive, ext, tables = inputs
    # Blocks of neighbouring sets: sets running at once on two threads would otherwise have
    # neighbouring rows in X, CS, outs and works, written every tick, and share the cache lines
    # at their boundaries. Several blocks per thread, taken in turn as threads get free: a fixed
    # half each left one core idle for as long as the host had slowed the other.
    n_blocks = min(n_threads * BLOCKS_PER_THREAD, len(X))
    bounds = np.linspace(0, len(X), n_blocks + 1).round().astype(int)

    def run_block(i: int) -> None:
        b = slice(bounds[i], bounds[i + 1])
        kernel.advance_sets(
            0, 1, X[b], P[b], CP[b], CS[b], n_ticks, ref, drive, ext, seeds[b], tables,
            table_of[b], rings[b], outs[b], engine.h, engine.dec, engine.sel, rec[b],
            engine.model.state_limits, status[b], works[b],
        )  # fmt: skip

    # the kernel releases the GIL: one Python thread per core runs sets side by side
    with ThreadPoolExecutor(max_workers=n_threads) as pool:
        list(pool.map(run_block, range(n_blocks)))


def run_batch(  # noqa: PLR0913 - the batch's optional input arrays, each keyword-only
    engine: Engine,
    params: np.ndarray,
    n_ticks: int,
    *,
    ref: np.ndarray | None = None,
    drive: np.ndarray | None = None,
    ext: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    controller_params: np.ndarray | None = None,
    seeds: np.ndarray | None = None,
    threads: int | None = None,
    cs0: np.ndarray | None = None,
) -> BatchResult:
    """Run N parameter sets (rows of `params`, e.g. from `model.param_vector`) from tick 0.

    Every set starts from `x0` (default: the engine's initial state) and the controller state
    `cs0` (default: a fresh controller); the
    inputs are shared; sets run on `threads` threads (default: the usable cores). A set that
    diverges is marked in `diverged`, its signals after the
    divergence are NaN, and the others run on; a set whose friction is too sharp for the step
    (see `check_step`) is not run, marked diverged, all NaN, with the reason in `messages`.
    """
    P = np.ascontiguousarray(params, dtype=float)
    if P.ndim != 2 or P.shape[1] != len(engine.model.param_names):
        raise ValueError(
            f"params: shape {P.shape} given, expected (N, {len(engine.model.param_names)})"
        )
    N = P.shape[0]
    status = np.zeros((N, 4))
    refused = check_steps(engine.model, P, engine.h, engine.nsub)
    status[[bool(m) for m in refused], 0] = 2.0  # not run: the kernel skips sets with a status
    engine.reset()
    X = np.tile(engine.x if x0 is None else np.asarray(x0, float), (N, 1))
    cs = engine.cs if cs0 is None else np.asarray(cs0, dtype=float)
    CS = np.tile(cs, (N, 1)) if cs.size else np.zeros((N, 0))
    if controller_params is None:
        CP = np.tile(engine.cp, (N, 1))
    else:
        CP = np.ascontiguousarray(np.broadcast_to(controller_params, (N, engine.cp.size)))
    seeds_arr = (
        np.full(N, engine.seed, dtype=np.int64) if seeds is None else np.asarray(seeds, np.int64)
    )
    rings = np.zeros((N, RING, signals.MEAS_SIZE))
    outs = np.zeros((N, signals.OUT_SIZE))
    ks = np.arange(n_ticks)
    rec_ticks = ks[ks % engine.dec == 0]
    rec = np.full((N, len(rec_ticks), len(engine.sel)), np.nan)
    ref2, drive2, ext2 = engine.tick_inputs(n_ticks, ref=ref, drive=drive, ext=ext)
    works = np.zeros((N, engine.work.size))
    n_threads = max(1, min(threads or default_threads(), N))
    # the noise tables depend on the plant alone: the engine's own kernel draws them
    tables, table_of = _shared_normals(engine.kernel, seeds_arr, n_ticks)
    sets = _Sets(X, P, CP, CS, seeds_arr, table_of, rings, outs, rec, status, works)
    for rows in _structures(engine, CP):
        whole = len(rows) == N
        group = sets if whole else sets.take(rows)
        kernel = engine.kernel_for(CP[rows[0]])
        inputs = (ref2, drive2, ext2, tables)
        _advance_blocks(kernel, engine, n_ticks, inputs, group, n_threads)
        if not whole:
            rec[rows], status[rows] = group.rec, group.status
    diverged = status[:, 0] != 0.0
    messages = []
    for b in range(N):
        if refused[b]:
            messages.append(f"not run: {refused[b]}")
        elif diverged[b]:
            k = int(status[b, 1])
            rec[b, rec_ticks > k, :] = np.nan
            messages.append(divergence_message(engine.model, status[b], engine.h))
        else:
            messages.append("")
    return BatchResult(
        t=rec_ticks * engine.h,
        names=engine.record_names,
        data=rec,
        diverged=diverged,
        messages=tuple(messages),
    )
