"""The machine's node set (feed_twin/machine/nodes.py, feed_twin/ros/machine_run.py): a sim node
per axis in its own process with its axis's controller node, one G-code node, one recorder;
every axis equals its in-process exchanges, the contour error is in the bag, the bag holds the
same bytes as with a controller process per axis and unpacked setpoints and as with the
controllers of all axes in one process, a killed axis node or controller process
stops the run naming the axes, and a machine file whose nodes do not fit its axes is refused
in one line."""

from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from nodes_support import last_json, raw_topics, run, start_run
from run_report_support import assert_report

from feed_twin.cli import main as cli_main
from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.io.bag import BagReader
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.nodes import chosen_processes, node_plan, write_axis_files
from feed_twin.nodeset.drive_host import Lockstep
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.ros.domain import reserve_domain_id

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
# a quarter circle in XY while Z rises (a helix), then the rotary table turns: B is a command only
PROGRAM = "G90 G54 G17\nG1 X10 Y0 Z140 F6000\nG3 X0 Y10 Z141 I-10 J0 F3000\nG1 B5 F3000\nM2\n"
# about 12 s of motion: a run 3-4x faster than real time is stopped long before its end
LONG_PROGRAM = "G90 G54\nG1 X100 Z120 F500\nM2\n"


def in_process_positions(axis_file: Path, program: Path, stamps: np.ndarray) -> np.ndarray:
    """The axis's table positions of the same exchanges without DDS (drive_host.Lockstep)."""
    nc = load_nc_config(axis_file)
    samples = Lockstep.for_config(axis_file).run_trajectory(
        plan_program(program, nc), until_ns=int(stamps[-1]), axis=nc.twin_axis
    )
    by_time = {s.t_ns: s.truth["table_position"] for s in samples}
    return np.array([by_time[int(t)] for t in stamps])


def machine_file(directory: Path, **ros: object) -> Path:
    """config/machine_default.yaml with the ros: fields `ros` replaced, written to `directory`."""
    data = yaml.safe_load(MACHINE.read_text())
    data["ros"] = {**data["ros"], **ros}
    for entry in data["axes"].values():
        entry["include"] = str(ROOT / "config" / entry["include"])
    config = directory / "machine.yaml"
    config.write_text(yaml.safe_dump(data))
    return config


def run_helix(directory: Path, program: Path, config: Path = MACHINE) -> dict:
    """`feed-twin run` of PROGRAM, written to `program`, on `config`: its JSON record."""
    program.write_text(PROGRAM)
    argv = [str(program), "--config", str(config), "--out", str(directory), "--name", "m"]
    with reserve_domain_id() as domain:
        code, out, err = run([*argv, "--json"], domain.domain_id)
    assert code == 0, err
    return assert_report(out, mode="machine nodes")  # the report of every mode


@pytest.fixture(scope="module")
def helix(tmp_path_factory) -> tuple[Path, dict]:
    """The helix on the machine file as it is (each controller in its sim's process, packed
    setpoints)."""
    directory = tmp_path_factory.mktemp("shared")
    program = directory / "helix.ngc"
    return program, run_helix(directory / "out", program)


@pytest.mark.ros
@pytest.mark.slow
def test_three_axes_in_their_own_nodes_equal_their_in_process_exchanges(helix):
    program, record = helix
    assert set(record["following_error_max_m"]) == {"x", "y", "z"}
    processes = sorted(p.stem for p in Path(record["logs"]).glob("*.log"))
    assert Path(record["rrd"]).stat().st_size > 10_000
    assert processes == ["recorder", "x_sim", "y_sim", "z_sim"]
    reader = BagReader(record["bag"])
    files = write_axis_files(load_machine_config(MACHINE), settle_s=0.2)  # the run's files
    states = {}
    for axis in ("x", "y", "z"):
        states[axis] = reader.columns(f"/cnc/{axis}/state", ["header.stamp", "table_position"])
        stamps = np.round(states[axis]["header.stamp"] * NS_PER_S).astype(np.int64)
        # lockstep: every axis ran the same exchanges, one per millisecond from t = 0
        np.testing.assert_array_equal(stamps, np.arange(len(stamps)) * 1_000_000)
        expected = in_process_positions(files[axis.upper()], program, stamps)
        np.testing.assert_allclose(
            states[axis]["table_position"], expected, rtol=0.0, atol=1e-9, err_msg=axis
        )
    assert len(states["x"]["header.stamp"]) == len(states["z"]["header.stamp"])
    # B has no plant: its command is in the bag, in radians, and no state
    b = reader.columns("/cnc/b/command", ["position"])["position"]
    assert b[-1] == pytest.approx(np.radians(5.0), abs=1e-12)
    # the contour error per sample, and the summary's figures are its max and RMS
    contour = reader.columns("/cnc/contour_error", ["data"])["data"]
    assert len(contour) == len(states["x"]["header.stamp"])
    assert record["contour_error_max_m"] == pytest.approx(contour.max(), rel=1e-12)
    assert 1e-7 < record["contour_error_max_m"] < 1e-4
    assert record["contour_error_rms_m"] < record["contour_error_max_m"]
    # the largest following error of an axis is at least the contour error it causes... and
    # the circle's end is back on the path: the last sample's error is well below the peak
    assert max(record["following_error_max_m"].values()) > 0.5 * record["contour_error_max_m"]
    assert contour[-1] < 0.2 * contour.max()


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize(
    ("ros", "processes"),
    [
        (
            {"controller_processes": "per_axis", "command_batch": False},
            ["recorder", "x_controller", "x_sim", "y_controller", "y_sim", "z_controller", "z_sim"],
        ),
        ({"controller_processes": "shared"}, ["controller", "recorder", "x_sim", "y_sim", "z_sim"]),
    ],
)
def test_every_controller_layout_records_the_same_bytes(helix, tmp_path, ros, processes):
    program, default = helix
    config = machine_file(tmp_path, **ros)
    other = run_helix(tmp_path / "out", program, config)  # program_state names its path
    assert sorted(p.stem for p in Path(other["logs"]).glob("*.log")) == processes
    a, b = raw_topics(default["bag"]), raw_topics(other["bag"])
    assert set(a) == set(b)
    # heartbeats and log lines carry wall time; every other topic is the run's result
    compared = [t for t in a if not t.endswith("/heartbeat") and t != "/rosout"]
    # per simulated axis command, drive_command, feedback, state, joint_states, clock,
    # program_state, run_state; B's command; the contour error and lag
    assert len(compared) == 3 * 8 + 1 + 2
    assert "/cnc/x/command_batch" not in a  # the controllers' packed copy is not recorded
    for topic in compared:
        assert a[topic] == b[topic], topic
    # a drive command for every exchange after the first, none past the run's end
    assert len(a["/cnc/z/drive_command"]) == len(a["/cnc/z/state"]) - 1 > 100


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize(
    ("victim", "ros", "named"),
    [
        # Z's sim and controller in one process
        ("z_sim", {}, "axis Z: z_sim node was killed by SIGKILL"),
        ("z_sim", {"controller_processes": "shared"}, "axis Z: z_sim node was killed by SIGKILL"),
        (
            "controller",
            {"controller_processes": "shared"},
            "axes X, Z: controller node was killed by SIGKILL",
        ),
    ],
)
def test_a_killed_axis_node_stops_the_run_within_a_second_naming_the_axis(
    tmp_path, victim, ros, named
):
    program = tmp_path / "long.ngc"
    program.write_text(LONG_PROGRAM)
    config = machine_file(tmp_path, **ros) if ros else MACHINE
    argv = [str(program), "--config", str(config), "--out", str(tmp_path), "--name", "k"]
    logs = tmp_path / "k.logs"
    with reserve_domain_id() as domain:
        proc = start_run([*argv, "--axes", "X,Z", "--json"], domain.domain_id)
        try:
            deadline = time.monotonic() + 180.0
            while time.monotonic() < deadline:
                if _simulated_time(logs / "z_sim.log") >= 0.2:  # states are in the bag by now
                    break
                time.sleep(0.1)
            pid = _child_pid(proc.pid, victim)
            os.kill(pid, signal.SIGKILL)
            killed_at = time.time()
            out, err = proc.communicate(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=10)
    record = last_json(out)
    assert record["exit_code"] == 137, err
    assert record["reason"].startswith(named), record
    assert len(record["reason"].splitlines()[0]) < 200
    # the bag is readable, Y is a command only, and X stopped within a second of the kill
    reader = BagReader(record["bag"])
    x = reader.columns("/cnc/x/state", ["header.stamp"])
    assert x["log_time_s"][-1] - killed_at < 1.0
    assert 0.0 < x["header.stamp"][-1] < 8.0  # it did not run the program to its end
    assert len(reader.columns("/cnc/y/command", ["position"])["position"]) > 0
    assert "/cnc/y/state" not in {t.name for t in reader.info.topics}


def _simulated_time(log: Path) -> float:
    """The last simulated time a sim node's log reported (PROGRESS lines), 0 before the first."""
    if not log.exists():
        return 0.0
    times = re.findall(r"^PROGRESS (\S+)$", log.read_text(errors="replace"), flags=re.M)
    return float(times[-1]) if times else 0.0


def _child_pid(parent: int, name: str) -> int:
    """The pid of the runner's child process that runs `name` (its log file's stem: an axis's
    node, or "controller", every axis's controller node in one node host)."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            status = (entry / "status").read_text()
            cmdline = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        ppid = int(next(ln.split()[1] for ln in status.splitlines() if ln.startswith("PPid:")))
        if ppid != parent:
            continue
        if name == "controller":
            if b"feed_twin.ros.host" in cmdline and b"controller" in cmdline:
                return int(entry.name)
            continue
        role = name.split("_")[1]
        axis_file = f"axis_{name.split('_')[0]}.yaml".encode()
        # the node's own module, or a node host with that role (a sim and its controller)
        runs = f"feed_twin.ros.{role}_node".encode() in cmdline or (
            b"feed_twin.ros.host" in cmdline and role.encode() in cmdline
        )
        if runs and any(arg.endswith(axis_file) for arg in cmdline):
            return int(entry.name)
    raise AssertionError(f"no process {name} under {parent}")


@pytest.mark.parametrize(
    ("ros", "message"),
    [
        ({"axis": "x"}, r"ros.axis = 'x': a machine's nodes take their namespace from the axis"),
        ({"machine": "mill"}, r"ros.machine = 'mill' does not match machine = 'cnc'"),
        (
            {"recorder_host": "own"},
            r"ros.recorder_host = 'own': a machine's recorder runs in the G-code node's process",
        ),
        (
            {"controller_processes": "one"},
            r"ros.controller_processes = 'one': must be one of with_sim, shared, per_axis$",
        ),
        ({"command_batch": "yes"}, r"ros.command_batch = 'yes': must be true or false$"),
        (
            {"lookahead": 5, "clock_divider": 10},
            r"yaml: axis X: ros.clock_divider = 10: must lie in \[1, lookahead - 1\] = \[1, 4\]",
        ),
    ],
)
def test_nodes_that_do_not_fit_the_axes_are_refused_in_one_line(tmp_path, capsys, ros, message):
    config = machine_file(tmp_path, **ros)
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = ["run", str(program), "--config", str(config), "--out", str(tmp_path), "--name", "m"]
    assert cli_main([*argv, "--json"]) == 1
    captured = capsys.readouterr()
    assert len(captured.err.strip().splitlines()) == 1
    reason = json.loads(captured.out.strip().splitlines()[-1])["reason"]
    assert re.search(message, reason), reason
    assert not (tmp_path / "m").exists()
    assert not (tmp_path / "m.logs").exists()


def test_start_splits_roles_only_where_their_processes_split(tmp_path, capsys):
    """`--start` by role on two computers: each side starts the processes of its roles, and a
    process that also hosts a role of the other side (a sim with its controller) is refused."""
    program = tmp_path / "p.ngc"
    program.write_text(PROGRAM)
    argv = ["run", str(program), "--config", str(MACHINE), "--out", str(tmp_path), "--name", "m"]
    assert cli_main([*argv, "--start", "sim", "--json"]) == 1
    reason = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["reason"]
    assert reason == (
        "--start sim: process x_sim also runs controller; name the process, "
        "or split the roles with ros.controller_processes: shared"
    )
    assert not (tmp_path / "m.logs").exists()
    plan = node_plan(load_machine_config(machine_file(tmp_path, controller_processes="shared")))
    processes = plan.processes(program=program, bag=tmp_path / "m", realtime=False, common=[])
    assert chosen_processes(processes, "sim") == ["x_sim", "y_sim", "z_sim"]
    assert chosen_processes(processes, "gcode,controller,recorder") == ["recorder", "controller"]
