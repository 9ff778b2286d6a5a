"""`NcBuffer`: the NC setpoints received so far and the one for an exchange time."""

from __future__ import annotations

import collections

from feed_twin.nodeset.wire import NcSample


class NcBuffer:
    """The NC setpoints received so far, and the rule that picks the one for an exchange time.

    The setpoint for t is the latest one stamped <= t, known once a setpoint stamped >= t has
    arrived (topics deliver in order). After the program has finished the last position is held
    at standstill (line -1), as a control does at program end.
    """

    def __init__(self) -> None:
        self._samples: collections.deque[NcSample] = collections.deque()
        self.latest_ns: int | None = None
        self.finished = False
        self._last: NcSample | None = None

    def add(self, sample: NcSample) -> None:
        self._samples.append(sample)
        self.latest_ns = sample.t_ns

    def finish(self) -> None:
        self.finished = True

    def for_time(self, t_ns: int) -> NcSample | None:
        samples = self._samples
        while len(samples) > 1 and samples[1].t_ns <= t_ns:
            samples.popleft()
        latest = self.latest_ns
        if samples and samples[0].t_ns <= t_ns and latest is not None and latest >= t_ns:
            self._last = samples[0]
            return samples[0]
        if self.finished and (self._last is not None or samples):
            last = samples[-1] if samples else self._last
            assert last is not None  # the condition above
            return NcSample(
                t_ns=t_ns,
                position_m=last.position_m,
                velocity_m_s=0.0,
                acceleration_m_s2=0.0,
                line=-1,
            )
        return None
