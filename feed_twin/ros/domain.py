"""Private ROS 2 domains, so that tests and runs on one machine never hear each other.

Two ROS 2 graphs with the same `ROS_DOMAIN_ID` on one host exchange discovery data, and a test
that subscribes to `/x/axis_state` would receive another run's samples. `reserve_domain_id`
hands out a domain ID that no other process on this machine holds, by taking an exclusive
`flock` on a per-ID lock file; the kernel drops the lock when the holder exits, even on SIGKILL,
so a crashed run never leaks its ID.

The lock files live in fixed, host-wide directories (LOCK_DIRS: `/run/feed_twin` and
`/dev/shm/feed_twin`, both RAM file systems emptied at boot), never in `$TMPDIR`: two runs with
different `TMPDIR`s once took the same domain and broke each other's lockstep. An ID is held
only when its lock is taken in every one of those directories that this user can use, so a
process that can write only one of them still meets the others there. Before an ID is handed
out, the host's UDP sockets are read as well (`/proc/net/udp*`): a DDS participant binds its
unicast ports in the domain's port block (7400 + 250 * id ...), so a domain someone already
uses without a lock (a ROS tool, an older feed_twin, a run in another lock directory) is
skipped. `private_graph_env` gives the environment for child processes: that ID, and discovery
limited to this host (no multicast leaves the machine).

This module does not import rclpy; it lives here because only ROS code needs it.
"""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass, field
from pathlib import Path

# Fast DDS maps a domain to UDP ports 7400 + 250 * id + offsets; above 101 they collide with
# Linux's ephemeral port range. Domain 0 is everyone's default, so it is never handed out.
FIRST_DOMAIN_ID = 1
LAST_DOMAIN_ID = 101
LOCK_DIRS = (Path("/run/feed_twin"), Path("/dev/shm/feed_twin"))
# The RTPS port mapping (DDSI-RTPS 9.6.1.1): PB + DG * domain + offsets, DG ports per domain.
PORT_BASE = 7400
PORT_DOMAIN_GAIN = 250
UDP_TABLES = (Path("/proc/net/udp"), Path("/proc/net/udp6"))


@dataclass(kw_only=True)
class DomainReservation:
    """A domain ID held by this process until `release()` or exit; usable as a context manager."""

    domain_id: int
    lock_path: Path
    _fds: tuple[int, ...] = field(default=(), repr=False)

    def release(self) -> None:
        for fd in self._fds:
            os.close(fd)  # closing the descriptor drops the flock
        self._fds = ()

    def __enter__(self) -> DomainReservation:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.release()


def lock_dirs() -> tuple[Path, ...]:
    """The lock directories this process can use (created, sticky and open to every user, on
    first use); raises RuntimeError when none is usable."""
    usable = []
    for directory in LOCK_DIRS:
        try:
            directory.mkdir(mode=0o1777, exist_ok=True)
            if directory.stat().st_uid == os.geteuid():
                directory.chmod(0o1777)  # mkdir's mode passes through the umask
        except OSError:
            pass
        if directory.is_dir() and os.access(directory, os.W_OK | os.X_OK):
            usable.append(directory)
    if not usable:
        raise RuntimeError(
            "no ROS domain lock directory is usable: "
            + ", ".join(str(d) for d in LOCK_DIRS)
            + " (each must be a writable directory)"
        )
    return tuple(usable)


def domain_ports(domain_id: int) -> range:
    """The UDP ports of a domain's participants (the RTPS port mapping's block)."""
    base = PORT_BASE + PORT_DOMAIN_GAIN * domain_id
    return range(base, base + PORT_DOMAIN_GAIN)


def bound_udp_ports(tables: tuple[Path, ...] = UDP_TABLES) -> frozenset[int]:
    """The local ports of this host's UDP sockets (this network namespace's)."""
    ports = set()
    for table in tables:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) > 1 and ":" in fields[1]:
                ports.add(int(fields[1].rpartition(":")[2], 16))
    return frozenset(ports)


def domain_in_use(domain_id: int, bound: frozenset[int] | None = None) -> bool:
    """Some process on this host has a DDS participant in `domain_id` (a socket in its block)."""
    ports = bound_udp_ports() if bound is None else bound
    block = domain_ports(domain_id)
    return any(port in block for port in ports)


def _lock_all(domain_id: int, directories: tuple[Path, ...]) -> list[int] | None:
    """Take the domain's lock in every directory (descriptors), or none of them (None)."""
    fds: list[int] = []
    for directory in directories:
        fd = os.open(
            directory / f"feed_twin-ros-domain-{domain_id}.lock", os.O_RDWR | os.O_CREAT, 0o666
        )
        fds.append(fd)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            for taken in fds:
                os.close(taken)
            return None
        if os.fstat(fd).st_uid == os.geteuid():
            os.fchmod(fd, 0o666)  # another user's run must be able to lock it too
    return fds


def reserve_domain_id(
    *, lock_dir: Path | None = None, udp_tables: tuple[Path, ...] = UDP_TABLES
) -> DomainReservation:
    """Reserve a ROS domain ID in [FIRST_DOMAIN_ID, LAST_DOMAIN_ID] that no other process holds
    or uses (`domain_in_use` on the sockets listed in `udp_tables`). `lock_dir`: one directory
    instead of LOCK_DIRS (tests).

    The search starts at an offset derived from the process ID, so concurrent callers rarely
    try the same IDs first. Raises RuntimeError naming the lock directories when all are taken.
    """
    directories = lock_dirs() if lock_dir is None else (lock_dir,)
    bound = bound_udp_ports(udp_tables)
    count = LAST_DOMAIN_ID - FIRST_DOMAIN_ID + 1
    start = os.getpid() % count
    in_use = 0
    for step in range(count):
        domain_id = FIRST_DOMAIN_ID + (start + step) % count
        if domain_in_use(domain_id, bound):
            in_use += 1
            continue
        fds = _lock_all(domain_id, directories)
        if fds is not None:
            return DomainReservation(
                domain_id=domain_id,
                lock_path=directories[0] / f"feed_twin-ros-domain-{domain_id}.lock",
                _fds=tuple(fds),
            )
    where = " and ".join(str(d) for d in directories)
    used = f", {in_use} of them in use by unlocked DDS participants" if in_use else ""
    raise RuntimeError(
        f"all ROS domain IDs {FIRST_DOMAIN_ID}..{LAST_DOMAIN_ID} are held by other processes "
        f"(lock files feed_twin-ros-domain-*.lock in {where}{used})"
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
