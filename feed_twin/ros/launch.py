"""Start node processes, watch them until all have ended, and say why they did.

`launch` is the process supervisor of `feed-twin run`, `run --shadow` and `feed-twin shadow`:
one process per name (a node, or a node host running several: feed_twin/ros/host.py), each
with its log file; a failed process ends the run, SIGINT/SIGTERM reach the producers first and
the recorder last, a deadline bounds the whole run. `log_record` reads the `PREFIX {json}` lines
the nodes print (TIMING, SHADOW), `foreign_messages` the FOREIGN lines of every node.
"""

from __future__ import annotations

import contextlib
import ctypes
import dataclasses
import json
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from feed_twin.ros.node_log import LogRecord, records

STOP_GRACE_S = 10.0  # [s] for nodes to finish after SIGTERM
PEER_NOTICE_S = 5.0  # [s] for nodes to notice a lost peer (0.9 s) and finish before SIGTERM


PARENT_PID_ENV = "FEED_TWIN_PARENT_PID"  # the runner's pid, which a node watches (runtime.py)
_PR_SET_PDEATHSIG = 1  # prctl option, linux/prctl.h


def _die_with_parent() -> None:
    """In the child before exec: the kernel sends SIGTERM when the runner dies, whatever
    killed it (SIGKILL included), so no node outlives its run. The node's own watch of the
    parent's pid (feed_twin.ros.runtime) covers the race of a runner that died before this."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


def stage(what: str) -> None:
    """A node launched by `launch` names the step it is in before its clock moves (its log's
    `STAGE <what>` line, which the progress bar shows); a node started otherwise says nothing."""
    if os.environ.get(PARENT_PID_ENV):
        print(f"STAGE {what}", file=sys.stderr, flush=True)


def key_fds(env: dict[str, str]) -> tuple[int, ...]:
    """The run key's descriptor (feed_twin.nodeset.auth.KEY_FD_ENV), inherited by the nodes
    only: it is close-on-exec everywhere else."""
    from feed_twin.nodeset.auth import KEY_FD_ENV

    text = env.get(KEY_FD_ENV, "")
    return (int(text),) if text.isdigit() else ()


class _Stop:
    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self, signum: int, frame: object) -> None:
        self.signum = signum


@dataclass
class Launched:
    code: int  # the run's exit code (130 after SIGINT/SIGTERM)
    reason: str  # why it ended, naming the node(s); empty for a normal end
    logs: dict[str, Path]  # role -> log file (stdout and stderr of the node)
    returncodes: dict[str, int | None]


def launch(
    commands: dict[str, list[str]],
    logs_dir: Path,
    *,
    env: dict[str, str],
    progress_role: str | None = None,
    show_progress: bool = False,
    deadline_s: float | None = None,
    stop_on_failure: bool = False,
    progress_total_s: float | None = None,
) -> Launched:
    """Start one process per role, watch them until all have ended, and say why they did.

    A node that exits with an error ends the run (the others notice its missing heartbeat and
    stop within a second, else they are told to); SIGINT/SIGTERM to this process is passed to
    the producers first and to the recorder last, so that it records what they sent;
    `progress_total_s` [s simulated] gives the progress bar its percent and ETA;
    `deadline_s` [s wall] bounds the whole run (the nodes are then terminated). With
    `stop_on_failure` the others are told to stop at once (a machine's axes do not watch each
    other's nodes), producers first and the recorder last. Every process is gone when this
    returns.
    """
    logs_dir.mkdir(parents=True, exist_ok=True)
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    stop = _Stop()
    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    code, reason = 0, ""
    first_failure: str | None = None
    timed_out = False
    started = time.monotonic()
    try:
        for role, argv in commands.items():
            logs[role] = logs_dir / f"{role}.log"
            with open(logs[role], "wb") as log:
                procs[role] = subprocess.Popen(
                    argv,
                    stdin=subprocess.DEVNULL,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env={**env, PARENT_PID_ENV: str(os.getpid())},
                    start_new_session=True,  # a terminal's Ctrl-C reaches the runner only
                    preexec_fn=_die_with_parent,
                    pass_fds=key_fds(env),
                )
        progress = _Progress(enabled=show_progress, total_s=progress_total_s)
        while any(p.poll() is None for p in procs.values()):
            if stop.signum is not None:
                reason = f"stopped by {signal.Signals(stop.signum).name}"
                _stop_in_order(procs, stop.signum)
                break
            for role, p in procs.items():
                rc = p.poll()
                if rc not in (None, 0) and first_failure is None:
                    first_failure = role
                    code = rc
                    reason = ""
            if first_failure is not None and stop_on_failure:
                _stop_in_order(procs, signal.SIGTERM)
                break
            if first_failure is not None:
                # Nodes that had seen the failed one stop on their own within a second (lost
                # heartbeat); the others (it died while starting) are told to stop.
                _wait_all(procs, PEER_NOTICE_S)
                break
            if deadline_s is not None and time.monotonic() - started > deadline_s:
                timed_out = True
                _wait_all(procs, 0.0)
                break
            if progress_role is not None:
                progress.update(logs[progress_role])
            time.sleep(0.05)
        progress.close()
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        for s, handler in previous.items():
            signal.signal(s, handler)
    returncodes = {r: p.returncode for r, p in procs.items()}
    if stop.signum is not None:
        code = 130
    elif timed_out:
        code = 1
        reason = f"the run took longer than {deadline_s:g} s; every node was stopped"
    else:
        code, reason = _failure(first_failure, code, returncodes, logs)
    return Launched(code=code, reason=reason, logs=logs, returncodes=returncodes)


def _failure(
    first: str | None, code: int, returncodes: dict[str, int | None], logs: dict[str, Path]
) -> tuple[int, str]:
    """The run's exit code and reason after its processes ended: the first failure seen while
    watching, with what the others said; else the first process that failed at its end."""
    failed = {r: rc for r, rc in returncodes.items() if rc}
    if first is None:
        if not failed:
            return code, ""
        first, code = next(iter(failed.items()))
        return code, _exit_text(first, code, logs[first])
    reason = _exit_text(first, code, logs[first])
    # What the others said: they name the node they lost.
    reason += "".join(
        f"\n  {_exit_text(role, rc, logs[role])}" for role, rc in failed.items() if role != first
    )
    return code, reason


def _stop_in_order(procs: dict[str, subprocess.Popen], signum: int) -> None:
    """Producers first, the recorder last, so that it records everything they sent."""
    producers = {r: p for r, p in procs.items() if r != "recorder"}
    for p in producers.values():
        if p.poll() is None:
            p.send_signal(signum)
    _wait_all(producers, STOP_GRACE_S)
    if "recorder" in procs and procs["recorder"].poll() is None:
        procs["recorder"].send_signal(signum)
    _wait_all(procs, STOP_GRACE_S)


def _wait_all(procs: dict[str, subprocess.Popen], grace_s: float) -> None:
    deadline = time.monotonic() + grace_s
    for p in procs.values():
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs.values():
        with contextlib.suppress(subprocess.TimeoutExpired):
            p.wait(timeout=max(0.0, deadline - time.monotonic()))


def _exit_text(process: str, code: int, log: Path) -> str:
    """`<process> node (<namespace>) exited with code <code>: <what it said last>`, the
    node's own words without rclpy's severity, time and logger (feed_twin.ros.node_log)."""
    said = _last_error(log)
    who = f"{process} node{_where(process, said)}"
    if code < 0:
        tail = f" (it had said: {said.message})" if said.is_error else ""
        return f"{who} was killed by {signal.Signals(-code).name}{tail}"
    return f"{who} exited with code {code}: {said.message}"


def _where(process: str, said: LogRecord) -> str:
    """` (cnc/x)`: the namespace of the node that said the error, its name too where the
    process is not named for it (a node host's other nodes); empty when no node said it."""
    node = said.node
    if node is None:
        return ""
    namespace, name = node
    if process != name and not process.endswith(f"_{name}"):
        return f" ({namespace}/{name})" if namespace else f" ({name})"
    return f" ({namespace})" if namespace else ""


_MACHINE_LINES = ("PROGRESS ", "STAGE ", "TIMING ", "CPU ", "FOREIGN ", "SHADOW ")
_CONTINUATION_LINES = 6  # at most, after an error's first line


def _last_error(log: Path) -> LogRecord:
    """The node's last error record (feed_twin.ros.node_log), at most 6 further lines kept
    and indented under its first, else its last 3 lines joined (naming no node: a process
    hosting several, say a machine's controllers, was not said by its last line to have
    failed); an empty log or one that cannot be read says so."""
    try:
        text = log.read_text(errors="replace")
    except OSError:
        return LogRecord(message="(no log)")
    said = list(records(text, skip=_MACHINE_LINES))
    errors = [r for r in said if r.is_error]
    if not errors:
        if not said:
            return LogRecord(message="(empty log)")
        return LogRecord(message=" | ".join(r.message.replace("\n", " ") for r in said[-3:]))
    first, *more = errors[-1].message.split("\n")
    lines = [first, *(ln.strip() for ln in more[:_CONTINUATION_LINES])]
    return dataclasses.replace(errors[-1], message="\n    ".join(lines))


def log_record(log: Path | None, prefix: str) -> dict | None:
    """The last `PREFIX {json}` line a node printed (None: none, or no log)."""
    if log is None:
        return None
    try:
        for line in reversed(log.read_text(errors="replace").splitlines()):
            if line.startswith(f"{prefix} "):
                return json.loads(line[len(prefix) + 1 :])
    except (OSError, ValueError):
        pass
    return None


_SLOW = re.compile(r"node '([^']+)' (?:is slow: no progress for|moves again after) (\S+) s")


def slow_nodes(logs: Path) -> dict[str, float]:
    """Nodes some peer said slow during the run (feed_twin.nodeset.liveness), with the
    longest time without progress said [s] (when said slow, or when it moved again), from the
    nodes' logs in `logs`."""
    found: dict[str, float] = {}
    for log in sorted(Path(logs).glob("*.log")):
        with contextlib.suppress(OSError):
            for name, seconds in _SLOW.findall(log.read_text(errors="replace")):
                found[name] = max(found.get(name, 0.0), float(seconds))
    return found


def slow_line(logs: Path) -> str | None:
    """One line naming the slow (not gone) nodes, or None."""
    slow = slow_nodes(logs)
    if not slow:
        return None
    named = ", ".join(f"'{n}' ({s:.2f} s without progress)" for n, s in sorted(slow.items()))
    return f"slow, not gone (the run went on): {named}"


def planned_duration_s(program, nc, *, settle_s: float = 0.0, json_out: bool) -> float | None:
    """[s] the program's planned duration plus `settle_s` on the NC `nc`, the progress bar's
    100 %; None when no bar is shown (planning costs time only a person watching needs) or
    the program cannot be planned here (an external NC)."""
    from feed_twin.gcode import GcodeError, plan_program
    from feed_twin.io.progress import wanted

    if program is None or not wanted(json_out=json_out):
        return None
    try:
        trajectory = plan_program(program, nc)
    except (GcodeError, ValueError, OSError):
        return None
    return float(trajectory.t_s[-1]) + settle_s if len(trajectory.t_s) else None


class _Progress:
    """The run's bar (feed_twin.io.progress) from the clock node's log: its `STAGE <what>`
    lines before the clock moves (compiling its kernels), then its `PROGRESS <t>` lines."""

    def __init__(self, *, enabled: bool, total_s: float | None = None) -> None:
        from feed_twin.io.progress import Progress, wanted

        self.bar = Progress(total_s=total_s, enabled=enabled and wanted(json_out=False))
        self.bar.stage("starting the nodes")
        self.last = 0.0
        self.offset = 0
        self.moving = False

    def update(self, sim_log: Path) -> None:
        now = time.monotonic()
        if not self.bar.enabled or now - self.last < 0.25:
            return
        self.last = now
        try:
            with open(sim_log, "rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except OSError:
            return
        self.offset += len(chunk)
        for line in chunk.decode(errors="replace").splitlines():
            if line.startswith("STAGE ") and not self.moving:
                self.bar.stage(line.removeprefix("STAGE ").strip())
            elif line.startswith("PROGRESS "):
                if not self.moving:
                    self.moving = True
                    self.bar.stage("running")
                self.bar.update(float(line.split()[1]))

    def close(self) -> None:
        self.bar.close()


def foreign_messages(logs: Iterable[Path]):
    """What the run's nodes refused as foreign, merged over their logs
    (feed_twin.nodeset.foreign.ForeignLedger)."""
    from feed_twin.nodeset.foreign import merge, parse_log

    records = []
    for log in logs:
        with contextlib.suppress(OSError):
            records += parse_log(log.read_text(errors="replace"))
    return merge(records)
