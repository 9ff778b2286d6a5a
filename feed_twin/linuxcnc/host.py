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
        if name in _LINUXCNC_PROCESSES and process_owner(int(entry.name)) is not None:
            found.append((int(entry.name), name))
    return found


def process_owner(pid: int) -> int | None:
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


_NML_KEYS = range(1001, 1006)  # the buffers of linuxcnc.nml, each a segment and a semaphore


def _sysv_keys(kind: str) -> set[int]:
    lines = Path(f"/proc/sysvipc/{kind}").read_text().splitlines()[1:]
    return {int(line.split()[0]) for line in lines}


def leftover_shared_memory() -> list[str]:
    """Keys of LinuxCNC's SysV shared-memory segments still present: the NML buffers of
    linuxcnc.nml (1001-1005), motion (100), RTAPI and HAL, the sampler and streamer FIFOs."""
    ours = {100, *_NML_KEYS, 0x48484C34, 0x48414C32}
    ours |= {base + channel for base in (0x48534130, 0x48535430) for channel in range(8)}
    return [hex(k) for k in sorted(_sysv_keys("shm") & ours)]


def leftover_semaphores() -> list[str]:
    """Keys of the SysV semaphores of LinuxCNC's NML buffers still present. They are made with
    mode 0700: one left by a run as one user makes another user's LinuxCNC fail ("semget:
    Permission denied")."""
    return [hex(k) for k in sorted(_sysv_keys("sem") & set(_NML_KEYS))]


def loopback_nml(source: Path, target: Path) -> Path:
    """Write `source`'s NML configuration to `target` without its network servers.

    Every buffer of LinuxCNC's linuxcnc.nml carries `TCP=5005`, which makes `linuxcncsvr`
    listen on 0.0.0.0:5005 and serve the command channel to any host; libnml has no option
    that binds it to one address. Without the option the buffers stay shared memory between
    the local processes (all of a run's) and nothing listens."""
    lines = []
    for line in source.read_text(encoding="utf-8").splitlines():
        if line.startswith("B "):
            line = " ".join(word for word in line.split() if not word.upper().startswith("TCP="))
        lines.append(line)
    target.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return target


def _kill_processes_of(uid: int) -> bool:
    """SIGKILL the user's LinuxCNC processes until two looks 50 ms apart find none (a halcmd
    killed mid-way may just have started an rtapi_app, which is set-uid root and runs as root
    until it has set itself up); True when there were any."""
    killed = False
    quiet_looks = 0
    deadline = time.monotonic() + 3.0
    while quiet_looks < 2 and time.monotonic() < deadline:
        stale = [
            pid
            for pid, name in leftover_processes()
            if process_owner(pid) == uid or (name == "rtapi_app" and process_owner(pid) == 0)
        ]
        quiet_looks = 0 if stale else quiet_looks + 1
        for pid in stale:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            killed = True
        time.sleep(0.05)
    return killed


def remove_leftovers(user: str | None) -> None:
    """Remove what a LinuxCNC that did not shut down itself left: its processes (killed by
    pid), its SysV shared memory and semaphores and /tmp/linuxcnc.lock. Under the host lock
    no other run can be using them."""
    uid = pwd.getpwnam(user).pw_uid if user is not None else os.getuid()
    killed = _kill_processes_of(uid)
    for key in leftover_shared_memory():
        subprocess.run(["ipcrm", "-M", key], capture_output=True, check=False)
    for key in leftover_semaphores():
        subprocess.run(["ipcrm", "-S", key], capture_output=True, check=False)
    with contextlib.suppress(FileNotFoundError, PermissionError):
        LINUXCNC_LOCKFILE.unlink()
    if killed:
        # the log files the killed script made with mktemp and would have removed
        for path in Path("/tmp").glob("linuxcnc.[dp][er][bi]*.*"):
            if _owner_of(path) == uid:
                path.unlink(missing_ok=True)


def leftovers(say: Callable[[str], None] = lambda text: None) -> list[str]:
    """What a LinuxCNC run left on this host (processes, shared memory, semaphores, its lock
    file), looked at under the host lock, so that a run in progress elsewhere is not mistaken
    for one."""
    with host_lock(say):
        found = [f"process {name} ({pid})" for pid, name in leftover_processes()]
        found += [f"shared memory {key}" for key in leftover_shared_memory()]
        found += [f"semaphore {key}" for key in leftover_semaphores()]
        if LINUXCNC_LOCKFILE.exists():
            found.append(str(LINUXCNC_LOCKFILE))
    return found
