"""A slow node is not a dead one: liveness decided on progress, with a tolerance from jitter.

Every node beats every 0.1 s (feed_twin.ros.runtime) from a thread of its own; the beat names
the node's process and its progress (`<role> <pid> <host> <turns>`: how many times the node's
own loop has turned, which a backlog or a stalled main thread stops while the beat thread goes
on). A peer is judged on the time since its progress was last heard to move, which a silent
beat and a stopped loop both lengthen. Past the tolerance it is:

- `gone` when its beats stopped and its process no longer lives (or is a zombie): said at
  once, the run stops. A dead process is a fact, so this waits for the floor only
  (`peer_timeout_s`), never for the jitter allowance;
- `slow` when its process lives on this host (or it still beats): said once, the run goes on,
  and said again when it moves again;
- `hung` when it has made no progress for `hung_s` (a minute by default: a host that stalls a
  process that long is not running a shadow any more), the run stops;
- `gone` too when its beats stopped and its process cannot be looked at (another host, an old
  beat without a pid): the silence alone decides.

The tolerance is the floor `peer_timeout_s` or, when this host has been stalling its threads,
more: HEARTBEAT_PERIOD_S plus JITTER_FACTOR times the worst lateness of the watcher's own
wake-ups over the last JITTER_WINDOW_S (`JitterMeter`). A peer's beat comes through a thread
scheduled by the same host, so a silence no longer than the host's own recent stalls says
nothing about the peer; and a watcher that was itself stopped for seconds does not blame its
peers for the beats it did not take.

Pure (no rclpy): the runtime sends and parses the beats and acts on the verdict.
"""

from __future__ import annotations

import os
import socket
from collections import deque
from dataclasses import dataclass
from pathlib import Path

HUNG_S = 60.0  # [s] a live process without progress this long is hung
HEARTBEAT_PERIOD_S = 0.1  # [s] between two beats of a node
JITTER_FACTOR = 2.0  # the tolerance allows twice the worst recent lateness
JITTER_WINDOW_S = 30.0  # [s] how far back the worst lateness is looked for


def heartbeat_text(role: str, turns: int | None = None) -> str:
    """What a node's heartbeat carries: its role, process id, host and (when given) how many
    times its loop has turned."""
    base = f"{role} {os.getpid()} {socket.gethostname()}"
    return base if turns is None else f"{base} {turns}"


@dataclass(frozen=True, kw_only=True)
class Beat:
    role: str
    pid: int | None  # None: the beat did not name its process
    host: str | None
    turns: int | None = None  # None: the beat did not say its progress


def parse_heartbeat(text: str) -> Beat:
    """A heartbeat's fields (a bare role, as older nodes send, has no process)."""
    parts = text.split()
    if len(parts) in (3, 4) and parts[1].isdigit():
        turns = int(parts[3]) if len(parts) == 4 and parts[3].isdigit() else None
        return Beat(role=parts[0], pid=int(parts[1]), host=parts[2], turns=turns)
    return Beat(role=text.strip(), pid=None, host=None)


def process_lives(pid: int) -> bool:
    """The process exists and is not a zombie (a killed process its parent has not reaped)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("State:"):
            return line.split()[1] not in ("Z", "X")
    return True


class JitterMeter:
    """The worst lateness of a periodic wake-up over the last `window_s` (kept as one maximum
    per second of the window, so its cost does not grow with the rate)."""

    def __init__(self, *, window_s: float = JITTER_WINDOW_S) -> None:
        if not window_s > 0.0:
            raise ValueError(f"window_s = {window_s!r}: must be > 0")
        self.window_s = window_s
        self._buckets: deque[tuple[int, float]] = deque()  # (second, worst lateness in it)
        self.worst_s = 0.0  # [s] the worst lateness since the start
        self.count = 0

    def add(self, now_s: float, lateness_s: float) -> None:
        """One wake-up at `now_s` [s, monotonic] that came `lateness_s` [s] after its time."""
        late = max(0.0, lateness_s)
        second = int(now_s)
        if self._buckets and self._buckets[-1][0] == second:
            late = max(late, self._buckets[-1][1])
            self._buckets[-1] = (second, late)
        else:
            self._buckets.append((second, late))
        while self._buckets and self._buckets[0][0] < second - self.window_s:
            self._buckets.popleft()
        self.worst_s = max(self.worst_s, late)
        self.count += 1

    def recent_s(self) -> float:
        """[s] the worst lateness within the window (0 before any wake-up)."""
        return max((late for _, late in self._buckets), default=0.0)

    def tolerance_s(self, floor_s: float) -> float:
        """[s] how long a peer may make no progress before it is said slow (module docstring)."""
        return max(floor_s, HEARTBEAT_PERIOD_S + JITTER_FACTOR * self.recent_s())


@dataclass(frozen=True, kw_only=True)
class PeerState:
    """What is known of a watched peer at one instant."""

    beat: Beat | None  # its latest beat
    silent_s: float  # [s] since its last beat
    still_s: float  # [s] since its progress was last heard to move (>= silent_s)


def verdict(peer: PeerState, *, floor_s: float, tolerance_s: float, hung_s: float) -> str:
    """'ok', 'slow', 'hung' or 'gone' for a peer (module docstring)."""
    beat = peer.beat
    pid = beat.pid if beat is not None and beat.host == socket.gethostname() else None
    local = pid is not None
    if peer.silent_s > floor_s and pid is not None and not process_lives(pid):
        return "gone"
    if peer.still_s <= tolerance_s:
        return "ok"
    if peer.silent_s > tolerance_s and not local:
        return "gone"
    return "hung" if peer.still_s > hung_s else "slow"
