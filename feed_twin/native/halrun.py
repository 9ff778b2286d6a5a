"""Running a HAL script in a bare `halrun`, as LinuxCNC needs it run on this kind of host.

`rtapi_app` refuses root, so as root the script runs as an unprivileged system user (created
if missing, with a home for rtapi's socket); only one realtime session can run on a host, so
runs take the host-wide lock that feed_twin's LinuxCNC runner takes too
(/tmp/feed_twin-linuxcnc.lock, an exclusive flock) and `halrun -U` cleans up after a failed one.
"""

from __future__ import annotations

import fcntl
import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_PATH = Path("/tmp/feed_twin-linuxcnc.lock")
RUN_USER = "feedtwin"
HAL_RUN_PACKAGE = "linuxcnc-uspace"


def run_user() -> str | None:
    """The user a HAL session runs as: None (this one) unless root."""
    if os.geteuid() != 0:
        return None
    try:
        pwd.getpwnam(RUN_USER)
    except KeyError:
        subprocess.run(
            [
                "useradd",
                "--system",
                "--create-home",
                "--home-dir",
                f"/var/lib/{RUN_USER}",
                "--shell",
                "/usr/sbin/nologin",
                RUN_USER,
            ],
            check=True,
            capture_output=True,
        )
    return RUN_USER


@contextmanager
def hal_session(
    script: str, *, files: dict[str, str] | None = None, timeout: float = 60.0
) -> Iterator[tuple[str, Path]]:
    """Run `script` (HAL commands) with `halrun -f` in a fresh directory under /tmp (the
    unprivileged user must reach it) holding `files` (name -> text, e.g. a shell script for
    `loadusr`); yields (stdout and stderr, that directory), removed after."""
    workdir = Path(tempfile.mkdtemp(prefix="feed_twin-hal-", dir="/tmp"))
    for name, text in (files or {}).items():
        (workdir / name).write_text(text)
        (workdir / name).chmod(0o644)
    try:
        yield _run(script, workdir, timeout), workdir
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def _run(script: str, workdir: Path, timeout: float) -> str:
    halrun = shutil.which("halrun")
    if halrun is None:
        raise RuntimeError(f"no `halrun` on the PATH: install the Debian package {HAL_RUN_PACKAGE}")
    user = run_user()
    path = workdir / "session.hal"
    path.write_text(script)
    if user is not None:
        os.chmod(workdir, 0o777)
        path.chmod(0o644)
    prefix = ["runuser", "-u", user, "--"] if user else []
    fd = os.open(LOCK_PATH, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        result = subprocess.run(
            [*prefix, halrun, "-f", str(path)],
            cwd=workdir,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        if result.returncode != 0:
            subprocess.run([*prefix, halrun, "-U"], capture_output=True, timeout=30)
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
    return result.stdout + result.stderr
