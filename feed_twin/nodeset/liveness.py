"""A slow node is not a dead one: what a silent peer is, told from its heartbeat and its process.

Every node beats every 0.1 s (feed_twin.ros.runtime). On a busy host a beat can come a second
late while the node works on; a dead node never beats again. The beat therefore names the
node's process (`<role> <pid> <host>`), and a peer that has been silent for the peer timeout
is:

- `gone` when its process no longer lives (or is a zombie): said at once, the run stops;
- `slow` when its process lives on this host: said once, the run goes on, and said again
  when the peer beats again;
- `hung` when its process lives but has not beaten for `hung_s` (a minute by default: a host
  that stalls a process that long is not running a shadow any more), the run stops;
- `gone` too when its process cannot be looked at (another host, an old beat without a pid):
  the silence alone decides, as before.

Pure (no rclpy): the runtime sends and parses the beats and acts on the verdict.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path

HUNG_S = 60.0  # [s] a live process silent this long is hung


def heartbeat_text(role: str) -> str:
    """What a node's heartbeat carries: its role, its process id and its host."""
    return f"{role} {os.getpid()} {socket.gethostname()}"


@dataclass(frozen=True, kw_only=True)
class Beat:
    role: str
    pid: int | None  # None: the beat did not name its process
    host: str | None


def parse_heartbeat(text: str) -> Beat:
    """A heartbeat's fields (a bare role, as older nodes send, has no process)."""
    parts = text.split()
    if len(parts) == 3 and parts[1].isdigit():
        return Beat(role=parts[0], pid=int(parts[1]), host=parts[2])
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


def silence_verdict(beat: Beat | None, silent_s: float, *, timeout_s: float, hung_s: float) -> str:
    """'ok', 'slow', 'hung' or 'gone' for a peer silent for `silent_s` (module docstring)."""
    if silent_s <= timeout_s:
        return "ok"
    if beat is None or beat.pid is None or beat.host != socket.gethostname():
        return "gone"
    if not process_lives(beat.pid):
        return "gone"
    return "hung" if silent_s > hung_s else "slow"
