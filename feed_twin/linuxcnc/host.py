"""The host side of running LinuxCNC: installed?, as whom, one run at a time, nothing left.

Only one LinuxCNC can run on a host (fixed shared-memory keys, /tmp/linuxcnc.lock), so every run
holds an exclusive flock on `LOCK_PATH`; a second caller waits for the first and says so.
LinuxCNC's `rtapi_app` refuses to run as root: as root a run switches to the user named by
FEED_TWIN_LINUXCNC_USER (default `feedtwin`, a system user created on first use, as
tools/setup.sh does); as any other user it runs as that user.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import pwd
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

LOCK_PATH = Path("/tmp/feed_twin-linuxcnc.lock")
LINUXCNC_LOCKFILE = Path("/tmp/linuxcnc.lock")
USER_ENV = "FEED_TWIN_LINUXCNC_USER"
DEFAULT_USER = "feedtwin"
CLOCK_MODULE = Path("/usr/lib/linuxcnc/modules/feedtwin_clock.so")
SYSTEM_PYTHON = "/usr/bin/python3"


class LinuxcncError(RuntimeError):
    """A LinuxCNC run failed; the message is one line that names the cause."""


def check_installed() -> None:
    """Raise LinuxcncError unless LinuxCNC and the project's clock component are installed."""
    if shutil.which("linuxcnc") is None or not Path(SYSTEM_PYTHON).exists():
        raise LinuxcncError(
            "LinuxCNC is not installed (no 'linuxcnc' on PATH): run tools/setup.sh as root, "
            "or apt-get install linuxcnc-uspace linuxcnc-uspace-dev"
        )
    if not CLOCK_MODULE.exists():
        raise LinuxcncError(
            f"LinuxCNC lacks the HAL component {CLOCK_MODULE.name}: run tools/setup.sh as root "
            "(halcompile --install config/linuxcnc/feedtwin_clock.comp)"
        )


def run_user() -> str | None:
    """The user LinuxCNC runs as: None (this one) unless root, else the unprivileged user."""
    if os.geteuid() != 0:
        return None
    name = os.environ.get(USER_ENV, DEFAULT_USER)
    try:
        entry = pwd.getpwnam(name)
    except KeyError:
        if name != DEFAULT_USER:
            raise LinuxcncError(f"{USER_ENV} = {name!r}: no such user") from None
        subprocess.run(
            ["useradd", "--system", "--create-home", "--home-dir", f"/var/lib/{name}",
             "--shell", "/usr/sbin/nologin", name],
            check=True, capture_output=True,
        )  # fmt: skip
        entry = pwd.getpwnam(name)
    if entry.pw_uid == 0:
        raise LinuxcncError(f"{USER_ENV} = {name!r}: must not be root (rtapi_app refuses root)")
    return name


@contextlib.contextmanager
def host_lock(say: Callable[[str], None]) -> Iterator[None]:
    """Hold the host-wide LinuxCNC lock; say once when another run holds it, then wait."""
    fd = os.open(LOCK_PATH, os.O_RDWR | os.O_CREAT, 0o666)
    with contextlib.suppress(PermissionError):
        os.fchmod(fd, 0o666)  # any user's run must be able to take it
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            say(f"waiting for another LinuxCNC run on this host (pid {holder}; lock {LOCK_PATH})")
            fcntl.flock(fd, fcntl.LOCK_EX)
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)


_LINUXCNC_PROCESSES = ("rtapi_app", "milltask", "linuxcncsvr", "io", "halcmd")


def leftover_processes() -> list[tuple[int, str]]:
    """(pid, name) of the live LinuxCNC processes on this host (any user)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            name = (entry / "comm").read_text().strip()
        except OSError:
            continue
        # (a killed process whose parent is gone stays a zombie where init does not reap)
        if name in _LINUXCNC_PROCESSES and _owner(int(entry.name)) is not None:
            found.append((int(entry.name), name))
    return found


def _owner(pid: int) -> int | None:
    """The real uid of a live process (None once it exited, also while it is a zombie); the
    real one, since rtapi_app is set-uid root."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    if fields.get("State", "").split()[:1] in (["Z"], ["X"]):
        return None
    return int(fields["Uid"].split()[0])


def _owner_of(path: Path) -> int | None:
    try:
        return path.stat().st_uid
    except FileNotFoundError:
        return None


def leftover_shared_memory() -> list[str]:
    """Keys of LinuxCNC's SysV shared-memory segments still present: the NML buffers of
    linuxcnc.nml (1001-1005), motion (100), RTAPI and HAL, the sampler and streamer FIFOs."""
    lines = Path("/proc/sysvipc/shm").read_text().splitlines()[1:]
    keys = {int(line.split()[0]) for line in lines}
    ours = {100, *range(1001, 1006), 0x48484C34, 0x48414C32}
    ours |= {base + channel for base in (0x48534130, 0x48535430) for channel in range(8)}
    return [hex(k) for k in sorted(keys & ours)]


def remove_leftovers(user: str | None) -> None:
    """Remove what a LinuxCNC that did not shut down itself left: its processes (killed by
    pid), its SysV shared memory and /tmp/linuxcnc.lock. Under the host lock no other run
    can be using them."""
    uid = pwd.getpwnam(user).pw_uid if user is not None else os.getuid()
    stale = [pid for pid, _ in leftover_processes() if _owner(pid) == uid]
    for pid in stale:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 2.0
    while any(_owner(pid) == uid for pid in stale) and time.monotonic() < deadline:
        time.sleep(0.01)
    for key in leftover_shared_memory():
        subprocess.run(["ipcrm", "-M", key], capture_output=True, check=False)
    with contextlib.suppress(FileNotFoundError, PermissionError):
        LINUXCNC_LOCKFILE.unlink()
    if stale:
        # the log files the killed script made with mktemp and would have removed
        for path in Path("/tmp").glob("linuxcnc.[dp][er][bi]*.*"):
            if _owner_of(path) == uid:
                path.unlink(missing_ok=True)
