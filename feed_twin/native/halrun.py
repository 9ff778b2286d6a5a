"""Running a HAL script in a bare `halrun`, as LinuxCNC needs it run on this kind of host.

`rtapi_app` refuses root, so as root the script runs as feed_twin.linuxcnc's unprivileged
system user; only one realtime session can run on a host, so runs take the host-wide lock of
feed_twin.linuxcnc's runner, and `halrun -U` cleans up after a failed one.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from feed_twin.linuxcnc.host import host_lock, run_user

HAL_RUN_PACKAGE = "linuxcnc-uspace"
# what halrun says when rtapi_app did not come up, which happens now and then right after
# another session exited
_NOT_STARTED = ("exited without becoming ready", "waitpid failed")


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
        log = _run(script, workdir, timeout)
        if any(sign in log for sign in _NOT_STARTED):
            log = _run(script, workdir, timeout)  # rtapi_app did not come up: once more
        yield log, workdir
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
    with host_lock(lambda message: None):
        result = subprocess.run(
            [*prefix, halrun, "-f", str(path)],
            cwd=workdir,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        if result.returncode != 0:
            subprocess.run([*prefix, halrun, "-U"], capture_output=True, timeout=30)
    return result.stdout + result.stderr


SINE_PINS = (
    ("pos_cmd", "f"),
    ("vel_cmd", "f"),
    ("acc_cmd", "f"),
    ("pos_fb", "f"),
    ("following_error", "f"),
    ("period_error", "b"),
    ("ticks", "s"),
    ("fault", "s"),
    ("time", "s"),
)
# the servo thread's own clock (config/linuxcnc/feedtwin_clock.comp, first in the thread): its
# tick count and the CLOCK_MONOTONIC start [s] of each period
CLOCK_PINS = (("clock_tick", "s", "tick"), ("clock_time_s", "f", "time-s"))


def sine_loop(
    n_periods: int,
    *,
    amplitude: float = 10.0,
    offset: float = 400.0,
    frequency_hz: float = 1.0,
    servo_period_ns: int = 1_000_000,
) -> dict[str, np.ndarray]:
    """The installed feed_twin_axis in a servo thread of its own with a sine position command
    [machine units] from siggen, its velocity and acceleration as feed-forward (scale), every
    period of `SINE_PINS` recorded by a sampler in the same thread; `time` is the component's
    execution time per call (LinuxCNC's `<function>.time` pin, CPU clocks); `clock_tick` and
    `clock_time_s` the thread's own clock (CLOCK_PINS) for its period timing."""
    w = 2.0 * math.pi * frequency_hz
    nets = "\n".join(
        [
            "net pos-cmd siggen.0.sine => feed-twin-axis.pos-cmd sampler.0.pin.0 scale.1.in",
            "net cos siggen.0.cosine => scale.0.in",
            "net vel-cmd scale.0.out => feed-twin-axis.vel-cmd sampler.0.pin.1",
            "net acc-cmd scale.1.out => feed-twin-axis.acc-cmd sampler.0.pin.2",
            *(
                f"net {name} feed-twin-axis.{name.replace('_', '-')} => sampler.0.pin.{i}"
                for i, (name, _) in enumerate(SINE_PINS)
                if i >= 3
            ),
            *(
                f"net {name} feedtwin-clock.0.{pin} => sampler.0.pin.{len(SINE_PINS) + i}"
                for i, (name, _, pin) in enumerate(CLOCK_PINS)
            ),
        ]
    )
    cfg = "".join(kind for _, kind in SINE_PINS) + "".join(kind for _, kind, _ in CLOCK_PINS)
    names = [name for name, _ in SINE_PINS] + [name for name, _, _ in CLOCK_PINS]
    script = f"""
loadrt threads name1=servo-thread period1={servo_period_ns}
loadrt feedtwin_clock
loadrt feed_twin_axis
loadrt siggen
loadrt scale count=2
loadrt sampler depth={n_periods + 1000} cfg={cfg}
addf feedtwin-clock.0 servo-thread
addf siggen.0.update servo-thread
addf scale.0 servo-thread
addf scale.1 servo-thread
addf feed-twin-axis servo-thread
addf sampler.0 servo-thread
setp siggen.0.amplitude {amplitude!r}
setp siggen.0.frequency {frequency_hz!r}
setp siggen.0.offset {offset!r}
setp scale.0.gain {w!r}
setp scale.0.offset {-w * offset!r}
setp scale.1.gain {-w * w!r}
setp scale.1.offset {w * w * offset!r}
setp feed-twin-axis.start-pos {offset!r}
{nets}
start
loadusr -w sh sample.sh
stop
"""
    sampler = f"halsampler -n {n_periods} > samples.txt\n"
    # the session runs the periods in (about) real time, plus LinuxCNC's start and stop
    timeout = n_periods * servo_period_ns * 1e-9 + 60.0
    with hal_session(script, files={"sample.sh": sampler}, timeout=timeout) as (log, workdir):
        path = workdir / "samples.txt"
        if not path.exists():
            raise RuntimeError(f"the HAL session recorded nothing:\n{log}")
        rows = np.loadtxt(path, ndmin=2)
    if rows.shape != (n_periods, len(names)):
        raise RuntimeError(f"the sampler gave {rows.shape}, not ({n_periods}, {len(names)})")
    return {name: rows[:, i] for i, name in enumerate(names)}
