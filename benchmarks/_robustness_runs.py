"""The run cases of benchmarks/robustness.py: faults, foreign publishers, disks, concurrency.

Each case starts `feed-twin run` as a user would and judges what it reports. Helpers check
that reported outputs are honest: a bag it names is read by an independent reader (rosbags),
an .rrd it names carries Rerun's footer, no node process outlives the run, no temporary file
is left behind.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml
from robustness import AXIS, CLI, ROOT, Case, Outcome, one_line_error

from feed_twin.io.bag import bag_paths
from feed_twin.nodeset.auth import KEY_FILE_ENV, new_key, write_key_file
from feed_twin.ros.domain import private_graph_env, reserve_domain_id
from feed_twin.ros.preflight import complete_rrd

SHORT = "%\nG21 G90 G54 G64\nG1 X10 F3000\nM30\n%\n"  # 0.25 s of motion
LONG = "G21 G90 G54\nG1 X60 F1200\nG1 X-60\nG1 X0\nM30\n"  # 12 s at 20 mm/s
FAR = "G21 G90 G54\nG0 X-200\nM30\n"
RUN_TIMEOUT_S = 300.0

INTRUDER = """
import sys, time, math, rclpy
from feed_twin_msgs.msg import AxisCommand, DriveCommand
from std_msgs.msg import String
from feed_twin.ros.dds import DATA_QOS, LATCHED_QOS
kind, seconds = sys.argv[1], float(sys.argv[2])
rclpy.init()
node = rclpy.create_node("intruder")
if kind == "axis":
    pub = node.create_publisher(AxisCommand, "/cnc/x/command", DATA_QOS)
    make = lambda k: AxisCommand(axis="X", position=0.3 + 0.2 * (k % 2), line=99)
elif kind == "drive":
    pub = node.create_publisher(DriveCommand, "/cnc/x/drive_command", DATA_QOS)
    make = lambda k: DriveCommand(axis="X", mode=10, enable=True, i_q=30.0)
elif kind == "truth":  # fake states and feedback: false figures, a lost lockstep if taken
    from feed_twin_msgs.msg import AxisFeedback, AxisState
    pub = node.create_publisher(AxisState, "/cnc/x/state", DATA_QOS)
    feedback = node.create_publisher(AxisFeedback, "/cnc/x/feedback", DATA_QOS)
    def make(k):
        feedback.publish(AxisFeedback(axis="X", scale_position=0.77, i_q=25.0))
        return AxisState(axis="X", table_position=0.77, following_error=0.5)
elif kind == "state":
    pub = node.create_publisher(String, "/cnc/x/program_state", LATCHED_QOS)
    make = lambda k: String(data=("finished 0", "finished nan", "x" * 9000)[k % 3])
else:  # an insider with the run's key (FEED_TWIN_RUN_KEY_FILE) sending garbage values
    import os
    from pathlib import Path
    from rclpy.serialization import serialize_message
    from feed_twin.nodeset.auth import Signer, read_key_file
    pub = node.create_publisher(AxisCommand, "/cnc/x/command", DATA_QOS)
    signer = Signer(read_key_file(Path(os.environ["FEED_TWIN_RUN_KEY_FILE"])), "/cnc/x/command")
    def make(k):
        msg = AxisCommand(axis="X", position=math.nan, velocity=1e30, line=99)
        return signer.sign(serialize_message(msg))
end = time.monotonic() + seconds
k = 0
while time.monotonic() < end:
    pub.publish(make(k))
    k += 1
    time.sleep(0.002)
"""


def program(work: Path, name: str, text: str) -> Path:
    path = work / f"{name}.ngc"
    path.write_text(text)
    return path


def start(args: list[str], env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        [*CLI, "run", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
    )  # fmt: skip


def finish(proc: subprocess.Popen, timeout: float = RUN_TIMEOUT_S) -> tuple[int | None, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=10)
        return None, out, err + f"\nhung for more than {timeout:g} s"
    return proc.returncode, out, err


def last_json(out: str) -> dict:
    try:
        return json.loads(out.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return {}


def honest(record: dict) -> list[str]:
    """Problems with the outputs a run reported (empty: none)."""
    problems = []
    bag = record.get("bag")
    if bag is not None:
        try:
            from rosbags.rosbag2 import Reader

            with Reader(bag) as reader:
                if reader.message_count <= 0:
                    problems.append("reported bag is empty")
        except Exception as exc:  # noqa: BLE001 - any failure of the independent reader counts
            problems.append(f"reported bag unreadable ({type(exc).__name__})")
        if list(Path(bag).glob("*.recovering")):
            problems.append("temporary .recovering file left")
    rrd = record.get("rrd")
    if rrd is not None and not complete_rrd(Path(rrd)):
        problems.append("reported .rrd is incomplete")
    return problems


def wait_for(predicate, timeout: float, period: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(period)
    return False


def sim_started(logs: Path) -> bool:
    try:
        return "PROGRESS" in (logs / "sim.log").read_text(errors="replace")
    except OSError:
        return False


def children(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(p) for p in out.split()]


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


def count_complete_messages(mcap: Path) -> int:
    """Complete message records in an MCAP file, read as a stream up to its first damage."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    count = 0
    with open(mcap, "rb") as f, contextlib.suppress(Exception):
        for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
            count += isinstance(record, Message)
    return count


def bag_messages(bag: str) -> int:
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        return reader.message_count


def judge(rc, out, err, *, code, needles=(), extra=()) -> Outcome:
    record = last_json(out)
    problems = list(extra)
    if rc != code:
        problems.append(f"exit {rc}, expected {code}")
    if record.get("exit_code") != rc:
        problems.append(f"JSON exit_code {record.get('exit_code')} != process {rc}")
    if "Traceback" in err or "Traceback" in out:
        problems.append("traceback")
    text = out + err
    problems += [f"no {n!r}" for n in needles if n not in text]
    problems += honest(record)
    reason = (record.get("reason") or "").splitlines()
    return Outcome(not problems, "; ".join(problems) or (reason[0][:150] if reason else "ok"))


# -- cases -------------------------------------------------------------------------------------


def baseline(work: Path) -> Outcome:
    p = program(work, "short", SHORT)
    rc, out, err = finish(start([str(p), "--out", str(work / "b"), "--name", "base", "--json"]))
    record = last_json(out)
    extra = [] if record.get("rrd") else ["no .rrd reported"]
    return judge(rc, out, err, code=0, needles=("following error max",), extra=extra)


def fe_trip(work: Path) -> Outcome:
    data = yaml.safe_load(AXIS.read_text())
    data["controller"]["position"]["following_error_limit_m"] = 2e-4
    cfg = work / "tight.yaml"
    cfg.write_text(yaml.safe_dump(data))
    p = program(work, "far", FAR)
    args = [str(p), "--config", str(cfg), "--out", str(work / "b"), "--name", "fe", "--json"]
    rc, out, err = finish(start(args))
    return judge(
        rc, out, err, code=1,
        needles=("drive fault 1 at t = ", "exceeds the limit 0.200 mm", "program line 2: G0 X-200"),
    )  # fmt: skip


def stop_by(sig: signal.Signals):
    def check(work: Path) -> Outcome:
        p = program(work, "long", LONG)
        name = f"stop_{sig.name}"
        proc = start([str(p), "--out", str(work / "b"), "--name", name, "--json", "--realtime"])
        started = wait_for(lambda: sim_started(work / "b" / f"{name}.logs"), 120)
        time.sleep(1.0)
        proc.send_signal(sig)
        rc, out, err = finish(proc)
        record = last_json(out)
        extra = [] if started else ["the run never started"]
        if record.get("interrupted") is not True:
            extra.append("JSON does not say interrupted")
        return judge(rc, out, err, code=130, needles=("interrupted",), extra=extra)

    return check


def kill_runner(work: Path) -> Outcome:
    p = program(work, "long", LONG)
    logs = work / "b" / "killed.logs"
    proc = start([str(p), "--out", str(work / "b"), "--name", "killed", "--realtime"])
    started = wait_for(lambda: sim_started(logs), 120)
    time.sleep(1.0)
    nodes = children(proc.pid)
    proc.kill()
    finish(proc, 10)
    gone = wait_for(lambda: not any(alive(n) for n in nodes), 5.0)
    problems = [] if started and nodes else ["the run never started"]
    if not gone:
        problems.append(f"{sum(alive(n) for n in nodes)} node process(es) outlived the runner")
    bag = work / "b" / "killed"
    recovered = None
    try:
        from feed_twin.io.bag import info

        info(bag)  # the recorder closed it on SIGTERM: complete as it stands
        state = bag_messages(str(bag))
        timing = next(
            json.loads(ln[len("TIMING ") :])
            for ln in (logs / "sim.log").read_text().splitlines()
            if ln.startswith("TIMING ")
        )
        from feed_twin.io.bag import BagReader

        samples = len(BagReader(bag).columns("/cnc/x/state", ["header.stamp"])["header.stamp"])
        recovered = samples / timing["steps"]
        detail = (
            f"{len(nodes)} nodes ended; bag {state} messages, state {samples}/{timing['steps']}"
        )
    except Exception as exc:  # noqa: BLE001
        problems.append(f"bag after the kill: {type(exc).__name__}: {exc}")
        detail = ""
    return Outcome(not problems, "; ".join(problems) or detail, recovered)


def kill_node(role: str, *, realtime: bool):
    """SIGKILL the process that hosts `role` (lockstep: the recorder records inside the sim's
    process; real time: its own); the runner must recover the bag."""

    def check(work: Path) -> Outcome:
        p = program(work, "long", LONG)
        name = f"kill_{role}"
        logs = work / "b" / f"{name}.logs"
        args = [str(p), "--out", str(work / "b"), "--name", name, "--json"]
        proc = start(args + (["--realtime"] if realtime else []))
        started = wait_for(lambda: sim_started(logs), 120)
        time.sleep(1.5)
        victim = _process_of(proc.pid, role)
        flushed = None
        if victim is not None:
            os.kill(victim, signal.SIGKILL)
            _, mcap = bag_paths(work / "b" / name)
            copy = work / f"{name}_as_left.mcap"
            shutil.copyfile(mcap, copy)  # before the runner rewrites it
            flushed = count_complete_messages(copy)
        rc, out, err = finish(proc)
        record = last_json(out)
        extra = [] if started and victim else [f"no {role} process found"]
        recovered = None
        if record.get("bag") and flushed:
            recovered = min(bag_messages(record["bag"]) / flushed, 1.0)
        outcome = judge(rc, out, err, code=rc if rc not in (0, None) else -1, extra=extra)
        outcome.recovered = recovered
        if rc == 0:
            outcome.passed, outcome.detail = False, "exit 0 after a killed node"
        return outcome

    return check


def _process_of(runner: int, role: str) -> int | None:
    for pid in children(runner):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        text = b" ".join(cmd).decode(errors="replace")
        if f"{role}_node" in text or (role == "sim" and "feed_twin.ros.host" in text):
            return pid
    return None


@contextlib.contextmanager
def tmpfs(path: Path, size: str, *, read_only: bool = False):
    path.mkdir(parents=True, exist_ok=True)
    options = f"size={size}" + (",ro" if read_only else "")
    subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], check=True)
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def disk_full(work: Path) -> Outcome:
    p = program(work, "long", LONG)
    with tmpfs(work / "small", "16m") as small:
        proc = start([str(p), "--out", str(small), "--name", "full", "--json", "--realtime"])
        started = wait_for(lambda: sim_started(small / "full.logs"), 120)
        time.sleep(1.0)
        free = shutil.disk_usage(small).free
        with contextlib.suppress(OSError), open(small / "filler", "wb") as f:
            f.write(bytes(max(free - 300_000, 0)))
        rc, out, err = finish(proc)
        record = last_json(out)
        extra = [] if started else ["the run never started"]
        leftovers = [q.name for q in small.rglob("*.recovering")]
        if leftovers:
            extra.append(f"left {leftovers}")
        if record.get("bag") is None:
            extra.append("no bag kept")
        outcome = judge(
            rc, out, err, code=1, needles=("file system of --out is full", "recovered"), extra=extra
        )
    return outcome


def disk_too_small(work: Path) -> Outcome:
    p = program(work, "long", LONG)
    with tmpfs(work / "tiny", "2m") as tiny:
        return one_line_error(["run", str(p), "--out", str(tiny / "bags")], 1, "MB free")


def disk_read_only(work: Path) -> Outcome:
    p = program(work, "short", SHORT)
    with tmpfs(work / "ro", "1m", read_only=True) as ro:
        return one_line_error(
            ["run", str(p), "--out", str(ro / "bags")], 1, "Read-only file system"
        )


def out_is_file(work: Path) -> Outcome:
    p = program(work, "short", SHORT)
    blocker = work / "a_file"
    blocker.write_text("x")
    return one_line_error(["run", str(p), "--out", str(blocker)], 1, "not a directory")


FOREIGN_TOPIC = {  # where each intruder sends (the insider signs: its messages are not foreign)
    "axis": "/cnc/x/command",
    "drive": "/cnc/x/drive_command",
    "state": "/cnc/x/program_state",
    "truth": "/cnc/x/state",
}


def foreign(kind: str, needle: str):
    def check(work: Path) -> Outcome:
        p = program(work, "long", LONG)
        name = f"foreign_{kind}"
        with reserve_domain_id() as domain:
            env = {**os.environ, **private_graph_env(domain.domain_id)}
            if kind == "insider":  # holds the run's key (as a node of the run would)
                key_file = work / f"{name}.key"
                key_file.unlink(missing_ok=True)
                write_key_file(key_file, new_key())
                env[KEY_FILE_ENV] = str(key_file)
            proc = start([str(p), "--out", str(work / "b"), "--name", name, "--json"], env)
            intruder = subprocess.Popen(
                [sys.executable, "-c", INTRUDER, kind, "90"], env=env, cwd=ROOT
            )
            try:
                rc, out, err = finish(proc)
            finally:
                intruder.kill()
                intruder.wait(timeout=10)
        record = last_json(out)
        logs = Path(record.get("logs") or work / "b" / f"{name}.logs")
        said = "".join(f.read_text(errors="replace") for f in logs.glob("*.log"))
        extra = [] if needle in said else [f"no {needle!r} in the node logs"]
        fe = record.get("following_error_max_m", 1.0)
        if not fe < 1e-3:  # the undisturbed program: about 0.07 mm
            extra.append(f"following error {fe * 1e3:.3f} mm: the foreign commands got through")
        topic = FOREIGN_TOPIC.get(kind)
        entry = (record.get("foreign_messages") or {}).get(topic or "", {})
        if topic and not any("intruder" in p for p in entry.get("publishers", ())):
            extra.append(f"the intruder is not named under foreign_messages[{topic!r}]")
        return judge(rc, out, err, code=0, extra=extra)

    return check


def concurrent(work: Path, *, own_tmpdirs: bool = False) -> Outcome:
    """Two runs at once; `own_tmpdirs`: each with its own TMPDIR (the domain locks do not
    live there)."""
    p = program(work, "short", SHORT)
    env = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}
    envs = [dict(env) for _ in range(2)]
    if own_tmpdirs:
        for i, e in enumerate(envs):
            (work / f"tmp{i}").mkdir(exist_ok=True)
            e["TMPDIR"] = str(work / f"tmp{i}")
    tag = "tmp" if own_tmpdirs else ""
    procs = [
        start([str(p), "--out", str(work / "b"), "--name", f"twin{tag}{i}", "--json"], envs[i])
        for i in range(2)
    ]
    results = [finish(q) for q in procs]
    outcomes = [judge(rc, out, err, code=0) for rc, out, err in results]
    records = [last_json(out) for _, out, _ in results]
    same = len({r.get("following_error_max_m") for r in records}) == 1
    problems = [o.detail for o in outcomes if not o.passed]
    if not same:
        problems.append(f"different figures: {[r.get('following_error_max_m') for r in records]}")
    return Outcome(not problems, "; ".join(problems) or "both runs alone in their domains")


def run_cases() -> list[Case]:
    cases = [
        Case("run_baseline", "fault", baseline),
        Case("fault_following_error_trip", "fault", fe_trip),
        Case("fault_sigint", "fault", stop_by(signal.SIGINT)),
        Case("fault_sigterm", "fault", stop_by(signal.SIGTERM)),
        Case("fault_sigkill_runner", "fault", kill_runner),
        Case("fault_sigkill_sim_and_recorder", "fault", kill_node("sim", realtime=False)),
        Case("fault_sigkill_recorder", "fault", kill_node("recorder", realtime=True)),
        Case("fault_sigkill_controller", "fault", kill_node("controller", realtime=False)),
        Case("disk_out_is_a_file", "disk", out_is_file),
        Case("foreign_axis_command", "foreign", foreign("axis", "foreign publisher on")),
        Case("foreign_drive_command", "foreign", foreign("drive", "foreign publisher on")),
        Case("foreign_program_state", "foreign", foreign("state", "refused")),
        Case("foreign_state_and_feedback", "foreign", foreign("truth", "refused")),
        Case("insider_nan_commands", "foreign", foreign("insider", "position = nan")),
        Case("concurrent_runs", "concurrent", concurrent),
        Case(
            "concurrent_runs_other_tmpdirs",
            "concurrent",
            lambda work: concurrent(work, own_tmpdirs=True),
        ),
    ]
    if os.geteuid() == 0:
        cases += [
            Case("disk_full_during_run", "disk", disk_full),
            Case("disk_too_small", "disk", disk_too_small),
            Case("disk_read_only", "disk", disk_read_only),
        ]
    else:
        print("not root: the tmpfs cases (disk full, too small, read-only) are skipped")
    return cases
