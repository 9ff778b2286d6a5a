"""Run one G-code program on LinuxCNC headless and receive every servo period.

    from feed_twin.linuxcnc.runner import LinuxcncRun, run_program

    result = run_program("part.ngc", nc=nc_config, servo=servo_for_axis(controller))
    result.trace.pos_cmd_m        # (n, 3) every 1 ms servo period, SI, t = tick * period

`run_program` blocks until the program ended and LinuxCNC shut down; `LinuxcncRun` is the same
as a context manager whose `poll()` hands out the rows while the program runs (the ROS 2 bridge
and the virtual-commissioning loop use it). Both raise `LinuxcncError` with one line: LinuxCNC
missing, an INI that does not load, a program LinuxCNC rejects (its message and line), LinuxCNC
dying mid-run, the reader or the caller falling behind. Any fault stops the machine (the display
program aborts and exits, LinuxCNC's own script shuts it down) and the rows received so far stay
in `rows_so_far()`.

Runs take the host-wide lock and run LinuxCNC as an unprivileged user (`feed_twin.linuxcnc.host`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import pwd
import queue
import re
import select
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from feed_twin.core.validate import require_nonnegative, require_positive
from feed_twin.gcode.config import NcConfig
from feed_twin.linuxcnc.check import rejection_in
from feed_twin.linuxcnc.host import (
    LinuxcncError,
    check_installed,
    host_lock,
    leftover_processes,
    loopback_nml,
    process_owner,
    remove_leftovers,
    run_user,
)
from feed_twin.linuxcnc.machine import INI_NAME, MM_PER_M, HalServo, write_machine
from feed_twin.linuxcnc.samples import ROW_HEADER, ServoTrace, rows_to_trace, sample_layout

EVENT_PREFIX = "feed_twin-display: "
_DISPLAY_SOURCE = Path(__file__).with_name("_display.py")
_PIPE_SIZE = 1 << 20  # the largest pipe an unprivileged process may ask for
GRACEFUL_S = 3.0  # [s] LinuxCNC's own shutdown takes 0.3-0.9 s
WATCH_S = 0.1  # [s] between two looks at whether each of LinuxCNC's processes still lives
DEFAULT_NML = Path("/usr/share/linuxcnc/linuxcnc.nml")
# LinuxCNC's long-lived processes, each a reason to stop the run when it dies: the servo thread
# stops with rtapi_app; without milltask, io or linuxcncsvr the servo thread goes on sending idle
# periods while nothing plans, runs or answers any more
WATCHED = {
    "rtapi_app": "realtime",
    "milltask": "task",
    "io": "I/O controller",
    "linuxcncsvr": "NML server",
}


@dataclass(frozen=True, kw_only=True)
class RunOptions:
    """How a program runs on LinuxCNC (all times in seconds)."""

    timeout_s: float = 600.0  # [s] longest program run before it is aborted
    settle_s: float = 0.1  # [s] periods recorded after the program's end
    start_timeout_s: float = 30.0  # [s] LinuxCNC start-up until the machine is homed
    # [s] a row older than this when it arrives is said once (the run goes on: the sampler's
    # FIFO holds the periods, nothing is lost)
    max_lag_s: float = 1.0
    # [s] a row older than this is a fault: the sampler FIFO (HalServo.sample_depth periods)
    # is about to overflow and periods would be lost; at most 90 % of the FIFO
    lag_limit_s: float = 100.0
    # [s] no servo period for this long while running is a fault (LinuxCNC alive but stalled:
    # a loaded host without a realtime kernel stalls its threads for a few hundred ms)
    stall_s: float = 3.0
    twin_joint: int | None = None  # joint whose plant is the caller (virtual commissioning)
    twin_delay: int = 1  # [periods] the twin's answer to period k is the feedback of k + this
    # a machine directory of one's own (machine.ini and its files) instead of the generated one
    machine_dir: Path | None = None

    def __post_init__(self) -> None:
        for name in ("timeout_s", "start_timeout_s", "max_lag_s", "lag_limit_s", "stall_s"):
            require_positive(name, getattr(self, name))
        require_nonnegative("settle_s", self.settle_s)
        if isinstance(self.twin_delay, bool) or not isinstance(self.twin_delay, int):
            raise ValueError(f"twin_delay = {self.twin_delay!r}: must be an int")
        if not 1 <= self.twin_delay <= 1000:
            raise ValueError(f"twin_delay = {self.twin_delay!r}: must lie in [1, 1000]")
        if self.twin_joint not in (None, 0, 1, 2):
            raise ValueError(f"twin_joint = {self.twin_joint!r}: must be None, 0, 1 or 2")


@dataclass
class RunState:
    """What the display program reported."""

    events: list[dict] = field(default_factory=list)
    output: deque = field(default_factory=lambda: deque(maxlen=40))
    error: str | None = None
    end: dict | None = None


class LinuxcncRun:
    """One LinuxCNC session running one program (a context manager; see the module doc)."""

    def __init__(
        self,
        program: str | Path,
        *,
        nc: NcConfig,
        servo: HalServo,
        options: RunOptions = RunOptions(),
        twin: Callable[[np.ndarray], np.ndarray] | None = None,
        say: Callable[[str], None] = print,
    ) -> None:
        self.program = Path(program)
        if (twin is None) != (options.twin_joint is None):
            raise ValueError("twin and options.twin_joint go together (virtual commissioning)")
        # rows -> the twin joint's feedback [m] for the next period of each (commissioning)
        self.twin = twin
        if not self.program.is_file():
            raise LinuxcncError(f"{self.program}: no such G-code program")
        self.nc, self.servo, self.options, self.say = nc, servo, options, say
        self.layout = sample_layout()
        self._tick_column = self.layout.index("tick")
        self.row_bytes = 8 * self.layout.row_width
        self.state = RunState()
        self._events: queue.Queue = queue.Queue()
        self._chunks: list[np.ndarray] = []
        self._delivered = 0  # chunks poll() has handed out
        self._partial = b""
        self._stack = contextlib.ExitStack()
        self._proc: subprocess.Popen | None = None
        self._samples_fd = -1
        self._twin_fd = -1
        self.started_wall = 0.0
        self.ended = False
        self._dead = False  # LinuxCNC's servo thread or script died: no graceful shutdown
        self._closing = False  # shutting down: rows are only kept
        self._watched: dict[int, str] = {}  # pid -> name of LinuxCNC's processes (WATCHED)
        self._watch_wall = 0.0
        self.fault_wall: float | None = None
        self.lag_max_s = 0.0  # [s] the oldest row's age at its arrival, over the run
        self._lag_said = False
        self._lag_limit_s = min(
            options.lag_limit_s, 0.9 * servo.sample_depth * servo.servo_period_s
        )

    def __enter__(self) -> LinuxcncRun:
        check_installed()
        user = run_user()
        try:
            self._stack.enter_context(host_lock(self.say))
            self._start(user)
        except BaseException:
            self._stack.close()
            raise
        return self

    def _start(self, user: str | None) -> None:
        workdir = Path(
            self._stack.enter_context(tempfile.TemporaryDirectory(prefix="feed_twin-lcnc-"))
        )
        if self.options.machine_dir is None:
            ini = write_machine(workdir, self.nc, self.servo, twin_joint=self.options.twin_joint)
        else:
            shutil.copytree(self.options.machine_dir, workdir, dirs_exist_ok=True)
            ini = workdir / INI_NAME
        rejection = rejection_in(self.program, workdir)
        if rejection is not None:
            raise LinuxcncError(str(rejection))
        program = workdir / ("program" + (self.program.suffix or ".ngc"))
        shutil.copyfile(self.program, program)
        display = workdir / "display.py"
        shutil.copyfile(_DISPLAY_SOURCE, display)
        display.chmod(0o755)
        samples = workdir / "samples.fifo"
        os.mkfifo(samples, 0o600)
        run = {
            "program": str(program),
            "mdi": self._mdi(),
            "joints": len(self.nc.axes),
            "sampler_cfg": self.layout.hal_cfg,
            "tick_column": self.layout.index("tick"),
            "samples_fifo": str(samples),
            "twin_fifo": None,
            "stop_file": str(workdir / "stop"),
            "max_backlog_ticks": round(self._lag_limit_s / self.servo.servo_period_s),
            "timeout_s": self.options.timeout_s,
            "settle_ticks": round(self.options.settle_s / self.servo.servo_period_s),
        }
        if self.options.twin_joint is not None:
            run["twin_fifo"] = str(workdir / "twin.fifo")
            os.mkfifo(run["twin_fifo"], 0o600)
        (workdir / "run.json").write_text(json.dumps(run), encoding="utf-8")
        text, found = re.subn(
            r"^DISPLAY\s*=.*$", f"DISPLAY = {display} {workdir / 'run.json'}",
            ini.read_text(encoding="utf-8"), count=1, flags=re.MULTILINE,
        )  # fmt: skip
        if not found:
            raise LinuxcncError(f"{ini.name}: no 'DISPLAY =' line in its [DISPLAY] section")
        ini.write_text(_without_network(text, workdir), encoding="utf-8")
        self.stop_file = Path(run["stop_file"])
        if user is not None:
            entry = pwd.getpwnam(user)
            for path in [workdir, *workdir.iterdir()]:
                os.chown(path, entry.pw_uid, entry.pw_gid)
        remove_leftovers(user)
        # Open the read end first, so that the display's blocking open for writing returns.
        self._samples_fd = os.open(samples, os.O_RDONLY | os.O_NONBLOCK)
        with contextlib.suppress(OSError):
            fcntl.fcntl(self._samples_fd, fcntl.F_SETPIPE_SZ, _PIPE_SIZE)
        command = ["linuxcnc", "-r", str(ini)]
        if user is not None:
            command = ["runuser", "-u", user, "--", *command]
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
        self.started_wall = time.monotonic()
        self._proc = subprocess.Popen(
            command, cwd=workdir, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, env=env, start_new_session=True,
        )  # fmt: skip
        self._stack.callback(self._shutdown, user)
        threading.Thread(target=self._read_output, daemon=True).start()
        if run["twin_fifo"]:
            self._twin_fd = self._open_twin_fifo(run["twin_fifo"])
        self._wait_ready()

    def _mdi(self) -> str:
        tol = f"{self.nc.path_tolerance_m * MM_PER_M:.6f}"
        return f"G64 P{tol} Q{tol}"

    def _open_twin_fifo(self, path: str) -> int:
        deadline = time.monotonic() + self.options.start_timeout_s
        while True:
            try:
                return os.open(path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # ENXIO until the display has opened its read end
                self._check_alive()
                if time.monotonic() > deadline:
                    raise LinuxcncError("LinuxCNC's display did not open the twin FIFO") from None
                time.sleep(0.005)

    def _read_output(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        for raw in self._proc.stdout:
            line = raw.decode(errors="replace").rstrip()
            if line.startswith(EVENT_PREFIX):
                self._events.put(json.loads(line[len(EVENT_PREFIX) :]))
            elif line:
                self.state.output.append(line)
        self._events.put({"event": "exit"})

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + self.options.start_timeout_s
        while not any(e["event"] == "ready" for e in self.state.events):
            self._drain_samples()
            self._handle_events(timeout=0.01)
            if time.monotonic() > deadline:
                self._fail(f"LinuxCNC did not start within {self.options.start_timeout_s} s")
        # (under the host lock every LinuxCNC process on the host is this run's)
        self._watched = {pid: name for pid, name in leftover_processes() if name in WATCHED}
        missing = set(WATCHED) - set(self._watched.values())
        if missing:
            self._dead = True
            self._fail(f"LinuxCNC started without its process(es) {', '.join(sorted(missing))}")

    def poll(self, timeout: float = 0.01) -> np.ndarray:
        """Rows (n, row_width) that arrived since the last call; empty once the run ended.

        Raises LinuxcncError on any fault (the machine is stopped by then)."""
        if self.ended:
            return np.empty((0, self.layout.row_width))
        select.select([self._samples_fd], [], [], timeout)
        rows = self._drain_samples()
        self._handle_events(timeout=0.0)
        new = self._chunks[self._delivered :]
        self._delivered = len(self._chunks)
        now = time.monotonic()
        if rows.size:
            self._last_row_wall = now
            # the oldest row of the batch waited longest
            lag = now - rows[0, len(ROW_HEADER) + self.layout.index("tick_time_s")]
            self.lag_max_s = max(self.lag_max_s, lag)
            if lag > self._lag_limit_s:
                self._fail(
                    f"the bridge fell behind: servo tick {int(self._tick(rows[0]))} arrived "
                    f"{lag:.1f} s late (limit {self._lag_limit_s:.1f} s: LinuxCNC's sampler "
                    "FIFO would overflow)"
                )
            if lag > self.options.max_lag_s and not self._lag_said:
                self._lag_said = True
                self.say(
                    f"the bridge is behind LinuxCNC: servo tick {int(self._tick(rows[0]))} "
                    f"arrived {lag * 1e3:.0f} ms late (bound {self.options.max_lag_s * 1e3:.0f} "
                    "ms); the run goes on, every period is kept"
                )
        elif self.state.end is not None:
            self._check_alive()
        if now - self._watch_wall > WATCH_S and self.state.end is None:
            self._watch_wall = now
            self._watch_processes()
        if not rows.size and self.state.end is None:
            silent = now - getattr(self, "_last_row_wall", now)
            if silent > self.options.stall_s:
                self._check_alive()
                self._dead = True
                self._fail(
                    f"LinuxCNC stopped mid-run: no servo period for {self.options.stall_s:.1f} s "
                    f"(last tick {self._last_tick}, {self._where()})"
                )
        if not new:
            return np.empty((0, self.layout.row_width))
        return new[0] if len(new) == 1 else np.concatenate(new)

    def _watch_processes(self) -> None:
        gone = [name for pid, name in self._watched.items() if process_owner(pid) is None]
        if gone:
            self._dead = True
            name = gone[0]
            self._fail(
                f"LinuxCNC died mid-run: its {WATCHED[name]} process {name} is gone (last tick "
                f"{self._last_tick}, {self._where()})"
            )

    def send_twin(self, periods: np.ndarray, positions_m: np.ndarray) -> None:
        """Feedback positions [m] of the twin joint for the servo periods `periods`, in order."""
        pairs = np.stack([periods, np.asarray(positions_m) * MM_PER_M], axis=1)
        data = pairs.astype("<f8").tobytes()
        while data:
            try:
                written = os.write(self._twin_fd, data)
            except BrokenPipeError:
                return  # the display program has ended: the run's end or fault says why
            except BlockingIOError:
                written = 0
                self._check_alive()
                time.sleep(0.0005)
            data = data[written:]

    def _tick(self, row: np.ndarray) -> float:
        return row[len(ROW_HEADER) + self.layout.index("tick")]

    @property
    def _last_tick(self) -> int:
        return int(self._tick(self._chunks[-1][-1])) if self._chunks else -1

    def _where(self) -> str:
        if not self._chunks:
            return "before the first period"
        line = self._chunks[-1][-1, len(ROW_HEADER) + self.layout.index("program_line")]
        return f"program line {int(line)}"

    def _drain_samples(self) -> np.ndarray:
        data = self._partial
        while True:
            try:
                chunk = os.read(self._samples_fd, _PIPE_SIZE)
            except BlockingIOError:
                break
            if not chunk:
                break
            data += chunk
        whole = len(data) - len(data) % self.row_bytes
        self._partial = data[whole:]
        rows = np.frombuffer(data[:whole], dtype="<f8").reshape(-1, self.layout.row_width)
        if rows.size:
            self._chunks.append(rows)
            if self.twin is not None and not (self._dead or self._closing):
                # row k's answer is the feedback of period k + delay
                periods = rows[:, len(ROW_HEADER) + self._tick_column] + self.options.twin_delay
                self.send_twin(periods, self.twin(rows))
        return rows

    def _handle_events(self, timeout: float) -> None:
        try:
            event = self._events.get(timeout=timeout) if timeout else self._events.get_nowait()
        except queue.Empty:
            return
        while True:
            self.state.events.append(event)
            kind = event["event"]
            if kind == "error":
                self._fail(f"LinuxCNC: {event['text']} ({self._program_where(event)})")
            if kind == "end":
                self.state.end = event
            if kind == "exit":
                self._on_exit()
            try:
                event = self._events.get_nowait()
            except queue.Empty:
                return

    def _program_where(self, event: dict) -> str:
        return f"{self.program}:{event['line']}" if event.get("line") else str(self.program)

    def _on_exit(self) -> None:
        self._drain_samples()
        end = self.state.end
        if end is not None and end["status"] == 0:
            self.ended = True
            return
        cause = _cause(self.state.output)
        if not any(e["event"] == "ready" for e in self.state.events):
            self._fail(f"LinuxCNC did not start: {cause}")
        self._dead = True
        self._fail(f"LinuxCNC died mid-run at tick {self._last_tick}, {self._where()}: {cause}")

    def _check_alive(self) -> None:
        if self._proc is not None and self._proc.poll() is not None:
            self._handle_events(timeout=0.5)
            self._on_exit()

    def _fail(self, message: str) -> None:
        self.fault_wall = self.fault_wall or time.monotonic()
        self.state.error = self.state.error or message
        self._request_stop()
        raise LinuxcncError(message)

    def _request_stop(self) -> None:
        with contextlib.suppress(OSError):
            self.stop_file.touch()

    def wait_end(self) -> None:
        """Poll until the program ended and LinuxCNC exited (rows stay in rows_so_far())."""
        while not self.ended:
            self.poll(0.01)

    def rows_so_far(self) -> np.ndarray:
        if not self._chunks:
            return np.empty((0, self.layout.row_width))
        return np.concatenate(self._chunks)

    def trace(self) -> ServoTrace:
        return rows_to_trace(self.rows_so_far(), self.layout, period_s=self.servo.servo_period_s)

    def __exit__(self, *exc_info: object) -> None:
        self._stack.close()

    def _shutdown(self, user: str | None) -> None:
        """Stop LinuxCNC: the display aborts and exits and LinuxCNC's script shuts down (under a
        second); when LinuxCNC's realtime part died, or the script is not done within
        GRACEFUL_S, its processes are killed and their shared memory and lock file removed."""
        self._request_stop()
        self._closing = True
        proc = self._proc
        assert proc is not None
        if not self._dead:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=GRACEFUL_S)
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        self._drain_samples()
        for fd in (self._samples_fd, self._twin_fd):
            if fd >= 0:
                os.close(fd)
        # LinuxCNC's script returns while its servers are still exiting (about 0.3 s)
        deadline = time.monotonic() + (0.0 if self._dead else 2.0)
        while leftover_processes() and time.monotonic() < deadline:
            time.sleep(0.02)
        remove_leftovers(user)


def _without_network(ini_text: str, workdir: Path) -> str:
    """The INI with its [EMC] NML_FILE replaced by a copy without network servers (see
    host.loopback_nml), so that linuxcncsvr listens on no port."""
    emc = re.search(r"^\[EMC\][^\[]*", ini_text, flags=re.MULTILINE)
    if emc is None:
        raise LinuxcncError("machine.ini: no [EMC] section")
    given = re.search(r"^NML_FILE\s*=\s*(\S+)\s*$", emc.group(0), flags=re.MULTILINE)
    source = DEFAULT_NML if given is None else workdir / given.group(1)
    if not source.is_file():
        raise LinuxcncError(f"machine.ini: [EMC] NML_FILE {source}: no such file")
    nml = loopback_nml(source, workdir / "feed_twin-local.nml")
    section = emc.group(0)
    if given is not None:
        section = section.replace(given.group(0), "")
    section = section.replace("[EMC]\n", f"[EMC]\nNML_FILE = {nml}\n", 1)
    return ini_text[: emc.start()] + section + ini_text[emc.end() :]


# LinuxCNC's own words for why it stopped, most specific first: a HAL or INI file line,
# then anything that says error.
_CAUSES = (
    re.compile(r"\S+\.(hal|ini|tcl):\d+: "),
    re.compile(r"error|can't|cannot|not found|does not exist", re.IGNORECASE),
)
_NOT_CAUSES = ("terminated with an error", "linuxcnc_debug.txt", "linuxcnc_print.txt", "dmesg")


def _cause(output: deque) -> str:
    lines = [line.strip() for line in output if not any(n in line for n in _NOT_CAUSES)]
    for pattern in _CAUSES:
        for line in lines:
            if pattern.search(line):
                return line.removeprefix("./")
    return lines[-1] if lines else "no output"


@dataclass(frozen=True, kw_only=True)
class RunResult:
    trace: ServoTrace
    events: list[dict]
    startup_s: float  # [s] from start to the machine homed and ready
    wall_s: float  # [s] the whole run, start-up and shutdown included
    overruns: int  # sampler FIFO overruns LinuxCNC counted (lost rows)
    twin: list[int] | None  # commissioning: [feedback values in time, values too late]


def run_program(
    program: str | Path,
    *,
    nc: NcConfig,
    servo: HalServo,
    options: RunOptions = RunOptions(),
    on_rows: Callable[[np.ndarray], None] | None = None,
    say: Callable[[str], None] = print,
) -> RunResult:
    """Run `program` on LinuxCNC to its end and return every servo period (see module doc)."""
    t0 = time.monotonic()
    with LinuxcncRun(program, nc=nc, servo=servo, options=options, say=say) as run:
        startup = time.monotonic() - t0
        while not run.ended:
            rows = run.poll(0.01)
            if on_rows is not None and rows.size:
                on_rows(rows)
    end = run.state.end or {}
    return RunResult(
        trace=run.trace(),
        events=run.state.events,
        startup_s=startup,
        wall_s=time.monotonic() - t0,
        overruns=int(end.get("overruns", 0)),
        twin=end.get("twin"),
    )
