#!/usr/bin/python3
"""LinuxCNC's headless "display": runs one program in AUTO and streams every servo period.

Started by the `linuxcnc` script as `[DISPLAY] DISPLAY = <this file> <run.json>` (the script
adds `-ini INI` before the arguments) once HAL, motion and task are up; LinuxCNC shuts down when
it exits. It runs under Debian's /usr/bin/python3 as the unprivileged LinuxCNC user, with only
the standard library and LinuxCNC's `linuxcnc` and `hal` modules (not feed_twin's environment).

Two threads:
- the reader drains the HAL sampler FIFO about every 0.2 ms and writes each row as float64
  `[receive time, pin values...]` to the samples FIFO of the runner (feed_twin.linuxcnc.runner);
  with a twin joint it also passes the twin's encoder values from the runner into the HAL
  streamer (virtual commissioning);
- the main thread resets E-stop, switches on, homes (immediate homing), sets the path tolerance
  by MDI, runs the program in AUTO and reports on stdout, one JSON object per line after the
  prefix `feed_twin-display: ` (states, LinuxCNC's error messages, the end).
"""

import contextlib
import json
import os
import select
import struct
import sys
import threading
import time

try:
    import hal
    import linuxcnc
except ImportError:  # imported, not run, outside Debian's Python (the core's import check)
    hal = linuxcnc = None

PREFIX = "feed_twin-display: "
READER_SLEEP_S = 0.0002
CLOCK_TICK_PIN = "feedtwin-clock.0.tick"
STATUS_POLL_S = 0.002


def emit(event, **fields):
    fields["event"] = event
    sys.stdout.write(PREFIX + json.dumps(fields) + "\n")
    sys.stdout.flush()


class Reader(threading.Thread):
    """Sampler FIFO -> samples FIFO; twin values FIFO -> streamer (when present)."""

    def __init__(self, comp, run):
        super().__init__(daemon=True)
        self.stream = hal.stream(comp, hal.sampler_base, run["sampler_cfg"])
        self.width = len(run["sampler_cfg"])
        self.tick_column = run["tick_column"]
        self.pack = struct.Struct(f"<{1 + self.width}d").pack
        self.out = os.open(run["samples_fifo"], os.O_WRONLY)
        self.max_backlog = run["max_backlog_ticks"]
        self.twin = None
        if run.get("twin_fifo"):
            self.twin = hal.stream(comp, hal.streamer_base, "f")
            self.twin_in = os.open(run["twin_fifo"], os.O_RDONLY | os.O_NONBLOCK)
            self.twin_buf = b""
            self.twin_late = 0  # values that came after their period had run (dropped)
            self.twin_written = 0
            self.twin_last = None
        self.twin_fed = False
        self.stop = threading.Event()
        self.last_tick = -1
        self.rows = 0
        self.failure = None

    def run(self):
        try:
            while not self.stop.is_set():
                self.pump()
                if self.twin is None:
                    time.sleep(READER_SLEEP_S)
                else:
                    # wake as soon as the twin answers: its value must beat the next period
                    select.select([self.twin_in], [], [], READER_SLEEP_S)
            self.pump()
        except Exception as exc:  # reported by the main thread, which stops the machine
            self.failure = f"{type(exc).__name__}: {exc}"
        finally:
            os.close(self.out)

    def pump(self):
        chunk = []
        stream = self.stream
        backlog = stream.depth
        # (the first drain takes the periods since HAL started, before this program ran)
        if self.rows and backlog > self.max_backlog:
            raise RuntimeError(
                f"the reader fell behind: {backlog} servo periods waiting in the sampler FIFO"
            )
        now = time.monotonic()
        while stream.readable:
            row = stream.read()
            if row is None:
                break
            chunk.append(self.pack(now, *row))
            self.last_tick = row[self.tick_column]
        if chunk:
            self.rows += len(chunk)
            os.write(self.out, b"".join(chunk))
        if self.twin is not None:
            self.feed_twin()

    def twin_counts(self):
        """(values written in time, values dropped as late) so far; None without a twin."""
        return None if self.twin is None else [self.twin_written, self.twin_late]

    def feed_twin(self):
        """The twin's (period, encoder value) pairs, in order, into the streamer, which hands
        out one value per period. A value whose period has started, or that would come out
        after its period because more values wait before it, is dropped (LinuxCNC keeps the
        previous feedback: a missed period); where values before it were dropped, the last
        value fills their places, so every value comes out in its own period."""
        try:
            data = os.read(self.twin_in, 65536)
        except BlockingIOError:
            data = b""
        self.twin_buf += data
        whole = len(self.twin_buf) - len(self.twin_buf) % 16
        pairs = list(struct.iter_unpack("<dd", self.twin_buf[:whole]))
        self.twin_buf = self.twin_buf[whole:]
        for period, value in pairs:
            # the period running now: feedtwin_clock sets it first in each period, before the
            # streamer hands out that period's value
            now = hal.get_value(CLOCK_TICK_PIN)
            ahead = int(period) - now - 1  # values that must come out before this one
            queued = self.twin.depth
            if ahead < queued:
                self.twin_late += 1
                continue
            held = value if self.twin_last is None else self.twin_last
            for _ in range(ahead - queued):
                self.twin.write((held,))
            self.twin.write((value,))
            self.twin_last = value
            self.twin_written += 1
            self.twin_fed = True


class StopRequestedError(Exception):
    """The runner asked for a stop (its stop file exists)."""


def check_stop(run):
    if os.path.exists(run["stop_file"]):
        raise StopRequestedError("stopped by the runner")


def wait_for(stat, condition, timeout_s, what, run):
    deadline = time.monotonic() + timeout_s
    while True:
        check_stop(run)
        stat.poll()
        if condition(stat):
            return
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout_s:.1f} s waiting for {what}")
        time.sleep(STATUS_POLL_S)


def check_errors(errors, reader, run):
    check_stop(run)
    message = errors.poll()
    if message:
        kind, text = message
        if kind in (linuxcnc.NML_ERROR, linuxcnc.OPERATOR_ERROR):
            raise RuntimeError(" ".join(text.split()))
        emit("message", text=" ".join(text.split()))
    if reader.failure:
        raise RuntimeError(reader.failure)
    if not reader.is_alive():
        raise RuntimeError("the sample reader stopped")


def start_machine(command, stat, run, reader):
    wait_for(stat, lambda s: s.task_state != 0, 10.0, "the task controller", run)
    if reader.twin is not None:
        # homing takes the feedback as it is: the twin's, not the streamer's initial 0
        wait_for(stat, lambda s: reader.twin_fed, 10.0, "the twin's first feedback", run)
        time.sleep(0.01)
    command.state(linuxcnc.STATE_ESTOP_RESET)
    command.state(linuxcnc.STATE_ON)
    wait_for(stat, lambda s: s.task_state == linuxcnc.STATE_ON, 5.0, "machine on", run)
    command.mode(linuxcnc.MODE_MANUAL)
    command.teleop_enable(0)
    command.home(-1)
    joints = run["joints"]
    wait_for(stat, lambda s: all(s.homed[:joints]), 5.0, "homing", run)
    command.mode(linuxcnc.MODE_MDI)
    wait_for(stat, lambda s: s.task_mode == linuxcnc.MODE_MDI, 5.0, "MDI mode", run)
    command.mdi(run["mdi"])
    command.wait_complete(5.0)
    stat.poll()
    emit("ready", settings=list(stat.settings))


def run_program(command, stat, errors, reader, run):
    command.mode(linuxcnc.MODE_AUTO)
    wait_for(stat, lambda s: s.task_mode == linuxcnc.MODE_AUTO, 5.0, "AUTO mode", run)
    command.program_open(run["program"])
    command.auto(linuxcnc.AUTO_RUN, 0)
    emit("started", tick=reader.last_tick, twin=reader.twin_counts())
    deadline = time.monotonic() + run["timeout_s"]
    started = False
    while True:
        check_errors(errors, reader, run)
        stat.poll()
        if stat.task_state != linuxcnc.STATE_ON:
            raise RuntimeError(f"LinuxCNC switched the machine off (task state {stat.task_state})")
        busy = stat.interp_state != linuxcnc.INTERP_IDLE or stat.queue > 0
        started = started or busy
        if started and not busy and stat.exec_state == linuxcnc.EXEC_DONE:
            break
        if time.monotonic() > deadline:
            raise RuntimeError(f"the program did not end within {run['timeout_s']:.1f} s")
        time.sleep(STATUS_POLL_S)
    check_errors(errors, reader, run)
    emit("program_done", tick=reader.last_tick, twin=reader.twin_counts())


def main(argv):
    with open(argv[-1], encoding="utf-8") as f:
        run = json.load(f)
    # the INI's NML file (the linuxcnc script exports it), not the module's default
    linuxcnc.nmlfile = os.environ.get("NMLFILE", linuxcnc.nmlfile)
    comp = hal.component("feedtwin-display")
    reader = Reader(comp, run)
    comp.ready()
    reader.start()
    command, stat, errors = linuxcnc.command(), linuxcnc.stat(), linuxcnc.error_channel()
    status = 0
    try:
        start_machine(command, stat, run, reader)
        run_program(command, stat, errors, reader, run)
        # the periods after the end: the servo loops settle
        end = reader.last_tick + run["settle_ticks"]
        while reader.last_tick < end and reader.is_alive():
            check_errors(errors, reader, run)
            time.sleep(STATUS_POLL_S)
    except StopRequestedError:
        status = 2
        command.abort()
    except Exception as exc:
        status = 1
        stat.poll()
        # the interpreter's line for a program it rejects, else the line in motion
        line = stat.read_line or stat.motion_line
        emit("error", text=str(exc), line=int(line), mode=int(stat.task_mode))
        with contextlib.suppress(linuxcnc.error):
            command.abort()
    reader.stop.set()
    reader.join(2.0)
    emit(
        "end",
        status=status,
        rows=reader.rows,
        overruns=reader.stream.num_overruns,
        twin=reader.twin_counts(),
    )
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv))
