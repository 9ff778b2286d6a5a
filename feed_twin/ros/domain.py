"""Private ROS 2 domains, so that tests and runs on one machine never hear each other.

Two ROS 2 graphs with the same `ROS_DOMAIN_ID` on one host exchange discovery data, and a test
that subscribes to `/x/axis_state` would receive another run's samples. `reserve_domain_id`
hands out a domain ID that no other process on this machine holds, by taking an exclusive
`flock` on a per-ID lock file; the kernel drops the lock when the holder exits, even on SIGKILL,
so a crashed run never leaks its ID. `private_graph_env` gives the environment for child
processes: that ID, and discovery limited to this host (no multicast leaves the machine).

This module does not import rclpy; it lives here because only ROS code needs it.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

# Fast DDS maps a domain to UDP ports 7400 + 250 * id + offsets; above 101 they collide with
# Linux's ephemeral port range. Domain 0 is everyone's default, so it is never handed out.
FIRST_DOMAIN_ID = 1
LAST_DOMAIN_ID = 101


@dataclass(kw_only=True)
class DomainReservation:
    """A domain ID held by this process until `release()` or exit; usable as a context manager."""

    domain_id: int
    lock_path: Path
    _fd: int | None = field(default=None, repr=False)

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self) -> DomainReservation:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def reserve_domain_id(*, lock_dir: Path | None = None) -> DomainReservation:
    """Reserve a ROS domain ID in [FIRST_DOMAIN_ID, LAST_DOMAIN_ID] that no other process holds.

    The search starts at an offset derived from the process ID, so concurrent callers rarely
    try the same IDs first. Raises RuntimeError naming the lock directory when all are taken.
    """
    directory = Path(tempfile.gettempdir()) if lock_dir is None else lock_dir
    count = LAST_DOMAIN_ID - FIRST_DOMAIN_ID + 1
    start = os.getpid() % count
    for step in range(count):
        domain_id = FIRST_DOMAIN_ID + (start + step) % count
        lock_path = directory / f"feed_twin-ros-domain-{domain_id}.lock"
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        return DomainReservation(domain_id=domain_id, lock_path=lock_path, _fd=fd)
    raise RuntimeError(
        f"all ROS domain IDs {FIRST_DOMAIN_ID}..{LAST_DOMAIN_ID} are held by other processes "
        f"(lock files feed_twin-ros-domain-*.lock in {directory})"
    )


def private_graph_env(domain_id: int) -> dict[str, str]:
    """Environment that puts a process into domain_id, discovering on this host only."""
    if not FIRST_DOMAIN_ID <= domain_id <= LAST_DOMAIN_ID:
        raise ValueError(
            f"domain_id = {domain_id!r}: must lie in [{FIRST_DOMAIN_ID}, {LAST_DOMAIN_ID}]"
        )
    return {"ROS_DOMAIN_ID": str(domain_id), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def run_domain(domain_id: int | None) -> tuple[DomainReservation | None, int]:
    """The domain of one `feed-twin run`: `domain_id` when the user names one (also through
    ROS_DOMAIN_ID in the environment), else a free one reserved for the run's life, so that
    two runs on one host never hear each other. Returns (reservation or None, domain ID)."""
    if domain_id is None:
        named = os.environ.get("ROS_DOMAIN_ID", "")
        if named.strip():
            if not named.strip().isdigit() or not 0 <= int(named) <= 232:
                raise ValueError(f"ROS_DOMAIN_ID = {named!r}: must be a whole number in [0, 232]")
            return None, int(named)
        reservation = reserve_domain_id()
        return reservation, reservation.domain_id
    if not 0 <= domain_id <= 232:
        raise ValueError(f"--domain-id {domain_id}: must lie in [0, 232]")
    return None, domain_id
