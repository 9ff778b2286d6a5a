"""A long job's progress on the terminal: percent, simulated time, ETA and the step it is in.

One bar on stderr (tqdm, which computes the rate and the ETA from recent updates), shown only
when stderr is a terminal and the run was not asked for `--json`, so a piped or logged run,
a test and a JSON consumer never see it. `stage` names what the job does before its clock
moves (planning the program, compiling the kernels: a first run compiles for a minute or more),
`update` sets the simulated time reached (the rate, the ETA and the time shown count from
its first call); `total_s` [s] gives the percent and the ETA (None:
the simulated time and the wall time only).

`PassBar` is the bar of a job made of passes of unknown length (`feed-twin diagnose`: the
nominal model, the rounds, the joint re-fit; feed_twin.analysis.passes): the pass by name, the
percent of the passes planned, the record time simulated so far and the ETA from the passes'
pace. A pass can take a minute: a thread redraws the bar every second, so that its clock
moves while the job works. Its `say` writes a line of the job's own output above the bar,
which stays below it.
"""

from __future__ import annotations

import os
import sys
import threading
from typing import NoReturn, TextIO

from tqdm import tqdm

_WITH_TOTAL = (
    "{desc}{percentage:3.0f}%|{bar:20}| {n:.2f}/{total:.2f} s simulated [{elapsed}<{remaining}]"
)
_WITHOUT_TOTAL = "{desc}{n:.2f} s simulated [{elapsed}]"
_PASSES = "{desc}{percentage:3.0f}%|{bar:20}| pass {n}/{total}{postfix} [{elapsed}<{remaining}]"


def wanted(*, json_out: bool, stream: TextIO | None = None) -> bool:
    """A bar only for a person at a terminal: not under --json, not into a pipe or a file."""
    stream = sys.stderr if stream is None else stream
    return not json_out and stream is not None and stream.isatty()


def _columns(stream: TextIO) -> int:
    """The terminal's width; a terminal that reports none (0, as a fresh pty does) gets 100,
    since tqdm drops the bar and its format at width 0."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or 100
    except (OSError, ValueError):
        return 100


def _bar(
    stream: TextIO | None,
    *,
    total: float | None,
    bar_format: str,
    min_interval_s: float,
    desc: str = "",
) -> tqdm[NoReturn]:
    """A bar on `stream` (stderr by default), removed when closed (updated by hand: no
    iterable, hence NoReturn in the stubs)."""
    file = sys.stderr if stream is None else stream
    return tqdm(
        total=total,
        desc=desc,
        file=file,
        bar_format=bar_format,
        ncols=_columns(file),
        mininterval=min_interval_s,
        leave=False,
    )


class Progress:
    """The bar of one job (module docstring); every method does nothing when not `enabled`."""

    def __init__(
        self,
        *,
        total_s: float | None,
        enabled: bool,
        stream: TextIO | None = None,
        min_interval_s: float = 0.1,  # [s wall] between redraws
    ) -> None:
        self.enabled = enabled
        self._bar: tqdm | None = None
        self._stage = ""
        self._moving = False
        if enabled:
            known = total_s is not None and total_s > 0
            self._bar = _bar(
                stream,
                total=total_s if known else None,
                bar_format=_WITH_TOTAL if known else _WITHOUT_TOTAL,
                min_interval_s=min_interval_s,
            )

    def stage(self, name: str) -> None:
        """What the job is doing now (shown before the figures)."""
        if self._bar is not None and name != self._stage:
            self._stage = name
            self._bar.set_description_str(f"{name}: ", refresh=True)

    def update(self, sim_s: float) -> None:
        """The simulated time reached [s]."""
        if self._bar is None:
            return
        bar = self._bar
        if not self._moving:
            # the rate and the ETA count from the clock's first move, not from the compilation
            self._moving = True
            bar.reset(total=bar.total)
        if bar.total is not None:
            sim_s = min(sim_s, bar.total)
        bar.update(sim_s - bar.n)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class PassBar:
    """The bar of a job made of passes (module docstring), shown from the first pass to `close`;
    every method but `say` does nothing when not `enabled`."""

    def __init__(
        self,
        *,
        enabled: bool,
        stream: TextIO | None = None,
        min_interval_s: float = 0.1,  # [s wall] between redraws
        tick_s: float = 1.0,  # [s wall] between the redraws of a pass that goes on
    ) -> None:
        self.enabled = enabled
        self._stream = stream
        self._min_interval_s = min_interval_s
        self._tick_s = tick_s
        self._bar: tqdm[NoReturn] | None = None  # drawn from the first pass on
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def begin(
        self, name: str, *, done: int, planned: int, simulated_s: float | None = None
    ) -> None:
        """Pass `name` begins after `done` of `planned`, `simulated_s` [s] of record simulated
        (None: not counted)."""
        if not self.enabled:
            return
        if self._bar is None:
            self._bar = _bar(
                self._stream,
                total=planned,
                bar_format=_PASSES,
                min_interval_s=self._min_interval_s,
                desc=f"{name}: ",  # tqdm draws at once: with the name, not a bare 0 %
            )
            self._stop.clear()
            self._ticker = threading.Thread(
                target=self._tick, args=(self._bar,), name="progress", daemon=True
            )
            self._ticker.start()
        bar = self._bar
        with bar.get_lock():  # not drawn half-changed by the ticker
            if done < bar.n:  # the job starts over (a program placed again): a new pace
                bar.reset(total=planned)
            bar.total = planned
            bar.set_description_str(f"{name}: ", refresh=False)
            simulated = "" if simulated_s is None else f"{simulated_s:.0f} s simulated"
            bar.set_postfix_str(simulated, refresh=False)
            bar.update(done - bar.n)
            bar.refresh()

    def _tick(self, bar: tqdm[NoReturn]) -> None:
        while not self._stop.wait(self._tick_s):
            bar.refresh()

    def say(self, line: str, stream: TextIO | None = None) -> None:
        """Print `line` (to stdout by default) above the bar, which is drawn again below it."""
        out = sys.stdout if stream is None else stream
        bar = self._bar
        if bar is None:
            print(line, file=out, flush=True)
            return
        with bar.get_lock():
            bar.clear(nolock=True)
            print(line, file=out, flush=True)
            bar.refresh(nolock=True)

    def close(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
            self._ticker = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
