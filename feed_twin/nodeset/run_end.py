"""Where a node-set run ends, known to the sim and to the controller alike.

The run ends `settle_s` after the stamp of the program's `finished` (or `stopped`) state. Both
nodes hear that state on `program_state` and keep a `RunEnd`, so they agree on the last exchange
without a message between them:
- the controller answers no feedback whose DriveCommand would be stamped past the end;
- the sim ends once it has run the last exchange at or before the end, whichever it learns first:
  that it has passed the end, or where the end is.
A sim that heard of the end only after its controller therefore waits instead of running on at
the held setpoint, and every run of one program records the same exchanges.

Pure: the ROS side passes in the parsed program state and the exchange times.
"""

from __future__ import annotations


class RunEnd:
    def __init__(self, settle_ns: int) -> None:
        if settle_ns < 0:
            raise ValueError(f"settle = {settle_ns} ns: must be >= 0")
        self.settle_ns = settle_ns
        self.end_ns: int | None = None  # [ns] the last exchange time that still runs
        self.word = ""  # the program state that set it: finished or stopped

    def learn(self, word: str, stamp_ns: int | None) -> bool:
        """Take a program state (parse_program_state's word and stamp); True when it set the
        end. The first end stands: a later state cannot move it."""
        if stamp_ns is None or self.end_ns is not None:
            return False
        self.end_ns = stamp_ns + self.settle_ns
        self.word = word
        return True

    def passed(self, t_ns: int) -> bool:
        """True when an exchange at `t_ns` lies past the end (False while the end is unknown)."""
        return self.end_ns is not None and t_ns > self.end_ns
