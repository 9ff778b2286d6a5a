"""The passes of a diagnosis as they begin, for whoever shows its progress (analysis.diagnose).

A diagnosis of a long record (a 60 s record, a 10 Hz mill log) runs for many seconds; its work
comes in passes of unknown length: the nominal model (compiled, then simulated), the rounds of
rank-fit-test (at most Options.max_effects, fewer when the library has nothing more to
explain), the joint selection (analysis.joint), the final joint re-fit, the appraisal and the
validation. The workflow announces each pass as it begins, with the passes done before it, the
passes planned and the record time simulated so far (parameter sets simulated x the record's
duration); a round not needed is skipped, so `done` may jump. The listener decides what to
show: the command line's bar (feed_twin.io.progress.PassBar), nothing in a library call. No
terminal code here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from feed_twin.io.measured import MeasuredRun


@dataclass(frozen=True, kw_only=True)
class Pass:
    """One pass of the workflow as it begins."""

    name: str  # what the pass does ("round 2 of at most 5", "final joint re-fit")
    done: int  # passes finished (or skipped) before this one
    planned: int  # passes in all, rounds counted at their most
    simulated_s: float  # [s] record time simulated by the workflow so far


PassListener = Callable[[Pass], None]


def ignore(_: Pass) -> None:
    """The listener of a diagnosis that nobody watches."""


class Passes:
    """Numbers the passes of one diagnosis (module docstring) and tells `listener` of each."""

    def __init__(
        self, listener: PassListener, *, rounds: int, validating: bool, t_s: NDArray[np.float64]
    ) -> None:
        self.listener = listener
        self.rounds = rounds
        # [s] the record time one simulation covers (`t_s`: the record's sample times)
        self.record_s = float(t_s[-1] - t_s[0])
        # nominal, the rounds, the joint selection, the joint re-fit, the appraisal, the
        # validation if asked
        self.planned = 1 + rounds + 3 + (1 if validating else 0)

    def _begin(self, name: str, done: int, simulations: int) -> None:
        self.listener(
            Pass(
                name=name,
                done=done,
                planned=self.planned,
                simulated_s=simulations * self.record_s,
            )
        )

    def nominal(self, step: str) -> None:
        """A step of the first pass: compiling the nominal model, simulating it."""
        self._begin(step, 0, 0)

    def round(self, number: int, simulations: int) -> None:
        """Round `number` (1-based) of ranking, fitting and testing begins."""
        self._begin(f"round {number} of at most {self.rounds}", number, simulations)

    def selection(self, simulations: int) -> None:
        """The joint selection (swaps of found effects for their rivals) begins."""
        self._begin("joint selection", 1 + self.rounds, simulations)

    def joint(self, simulations: int) -> None:
        self._begin("final joint re-fit", 2 + self.rounds, simulations)

    def appraisal(self, simulations: int) -> None:
        self._begin("appraising the final model", 3 + self.rounds, simulations)

    def validation(self, run: MeasuredRun | None, simulations: int) -> None:
        """The validation on `run` begins (nothing without one)."""
        if run is not None:
            self._begin(f"validating on {run.source}", 4 + self.rounds, simulations)
