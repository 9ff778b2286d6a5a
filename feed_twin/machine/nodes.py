"""The machine's ROS node set, planned in plain Python: which node runs where, with which file.

Per simulated axis a sim (drive) node and a controller node in the axis's namespace
`/<machine>/<axis>` (the single-axis nodes, feed_twin/ros/*_node.py, unchanged in what they
compute); each sim in its own process with its axis's controller node beside it
(`ros.controller_processes: with_sim`, the default: a drive closes its axis's loops itself, as a
CiA 402 drive in cyclic synchronous position mode does, and the exchange between controller and
drive then costs no datagram; docs/performance.md), or the controller nodes of every axis
together in one process (`shared`: one control for all axes, the NC's side of a link between
computers) or each in its own (`per_axis`); one G-code node that commands every NC axis and one
recorder
that records every axis into one bag. Each axis's nodes read one axis file that the runner
writes (`axis_documents`): the axis's plant (with its weight and counterbalance), engine and
controller from the machine file, the machine's NC with `twin_axis` set to that axis, and the
machine's `ros:` section with the axis's namespace. The G-code and recorder nodes live in the
first axis's namespace and also serve the others (`--machine-axes`): they beat and watch peers
there and wait for every axis's end of run.

Lockstep across axes: each sim advances when its controller's DriveCommand arrives, each
controller when the NC setpoint for its feedback's time is known, and the G-code node publishes
setpoints only up to `ros.lookahead` periods ahead of the slowest axis's clock (every sim
publishes `<namespace>/clock`). So every axis runs the same deterministic exchanges as alone,
and no axis runs more than lookahead + clock_divider exchanges ahead of another.

After the run, `read_machine_bag` reads every axis's command and state back from the bag and
measures the contour error (feed_twin.machine.contour) on the sample grid of the states.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from feed_twin.core.config import ConfigError, load_yaml
from feed_twin.machine.config import MachineConfig, axis_sections
from feed_twin.machine.contour import ContourError, contour_error
from feed_twin.nodeset.topics import AxisTopics

NODE_ROS_NAME_KEYS = ("axis",)  # the machine's axes name their nodes' namespaces themselves
RECORDER_PROCESS = "recorder"  # hosts the recorder and the G-code node
CONTROLLER_PROCESS = "controller"  # hosts every axis's controller node (shared layout)
GCODE_PROCESS = "gcode"  # the G-code node alone, when the recorder runs elsewhere
# where the recorder runs: beside the G-code node (a machine's), or an axis file's
# ros.recorder_host: in its sim's process (sim), its own (own), or auto (NodePlan._recorder_place)
RECORDER_PLACES = ("gcode", "sim", "own", "auto")
# ros.controller_processes: "with_sim" (the default), each axis's controller node in its sim's
# process (`<axis>_sim`): the exchange's DriveCommand and feedback pass within one process and
# one thread, without a datagram or a wake-up; "shared", one process for every axis's
# controller node (so they can run on the NC's computer, away from the sims); "per_axis", a
# process per axis's controller node
CONTROLLER_LAYOUTS = ("with_sim", "shared", "per_axis")
DEFAULT_CONTROLLER_LAYOUT = "with_sim"
# ros.command_batch: true, the G-code node sends each axis's controller the setpoints one clock
# message lets it publish as one message (gcode_node --command-batch); false, one each
MACHINE_ROS_KEYS = ("controller_processes", "command_batch")  # the machine's own, not an axis's
# [s] a peer silent this long is lost. A dead process is noticed by the runner at once
# (launch's stop_on_failure); heartbeats find hung nodes and nodes on other computers. With
# seven processes on two cores at load 15 the recorder's process went 0.8 s without taking
# heartbeats (it named every other axis's nodes together), so the machine waits longer.
PEER_TIMEOUT_S = 2.0


def axis_documents(
    machine: MachineConfig, *, settle_s: float | None = None
) -> dict[str, dict[str, Any]]:
    """NC axis name -> the single-axis config (plant, engine, controller, nc, ros) its nodes
    read; ConfigError (one line) where the machine's `ros:` section does not fit its axes.
    `settle_s` replaces ros.settle_s (the run's --settle)."""
    path = Path(machine.source)
    data = load_yaml(path)
    ros = data.get("ros") or {}
    if not isinstance(ros, dict):
        raise ConfigError(f"{path}: ros: expected a mapping, got {ros!r}")
    for key in NODE_ROS_NAME_KEYS:
        if key in ros:
            raise ConfigError(
                f"{path}: ros.{key} = {ros[key]!r}: a machine's nodes take their namespace from "
                f"the axis (axes.X runs /{machine.name}/x); remove it"
            )
    if "recorder_host" in ros:
        # the single-axis choice (the recorder in the sim's process or its own) has no
        # meaning here: one recorder serves every axis, beside the G-code node
        raise ConfigError(
            f"{path}: ros.recorder_host = {ros['recorder_host']!r}: a machine's recorder runs in "
            f"the G-code node's process (its copies of the axes' messages come packed, "
            f"ros.record_batch); remove it"
        )
    if ros.get("machine", machine.name) != machine.name:
        raise ConfigError(
            f"{path}: ros.machine = {ros['machine']!r} does not match machine = "
            f"{machine.name!r} (the nodes' namespace /{machine.name}/<axis>)"
        )
    machine_settings(machine)  # checked here, before any file is written
    ros = {k: v for k, v in ros.items() if k not in MACHINE_ROS_KEYS}
    docs = {}
    for key in machine.axes:
        sections, _, _ = axis_sections(data["axes"][key], key, machine.nc, path)
        docs[key] = {
            **{k: v for k, v in sections.items() if k in ("plant", "engine", "controller")},
            "nc": {**data["nc"], "twin_axis": key},
            "ros": {**ros, "machine": machine.name, "axis": key.lower()},
        }
        if settle_s is not None:
            docs[key]["ros"]["settle_s"] = settle_s
    return docs


def machine_settings(machine: MachineConfig) -> tuple[str, bool]:
    """The machine file's ros.controller_processes (default "with_sim") and ros.command_batch
    (default true); ConfigError (one line) for a value they cannot take."""
    path = Path(machine.source)
    ros = load_yaml(path).get("ros") or {}
    ros = ros if isinstance(ros, dict) else {}
    layout = ros.get("controller_processes", DEFAULT_CONTROLLER_LAYOUT)
    if layout not in CONTROLLER_LAYOUTS:
        raise ConfigError(
            f"{path}: ros.controller_processes = {layout!r}: must be one of "
            f"{', '.join(CONTROLLER_LAYOUTS)}"
        )
    batch = ros.get("command_batch", True)
    if not isinstance(batch, bool):
        raise ConfigError(f"{path}: ros.command_batch = {batch!r}: must be true or false")
    return layout, batch


def write_axis_files(
    machine: MachineConfig, directory: Path | None = None, *, settle_s: float | None = None
) -> dict[str, Path]:
    """Each simulated axis's config file (the nodes' --config), by default under the kernel
    cache in a directory named by the file's hash: the generated plant kernel names its config
    file, so a new path for the same axis would compile it again (16 s of CPU per axis), and
    runs of one machine (any --axes) share the compiled kernels this way."""
    return write_documents(machine, axis_documents(machine, settle_s=settle_s), directory)


def write_documents(
    machine: MachineConfig, documents: dict[str, dict[str, Any]], directory: Path | None
) -> dict[str, Path]:
    """Axis -> the file its nodes read, holding `documents[axis]` (write_axis_files)."""
    # the header names the machine, not its file: a copy of the file elsewhere with the same
    # axes (a benchmark's variant of ros.controller_processes) reuses the compiled kernels
    docs = {
        key: f"# axis {key} of machine {machine.name}, written for its nodes\n"
        + yaml.safe_dump(doc, sort_keys=False)
        for key, doc in documents.items()
    }
    files = {}
    for key, text in docs.items():
        where = directory
        if where is None:
            from feed_twin.sim.kernel import cache_dir

            digest = hashlib.sha256(text.encode()).hexdigest()[:16]
            where = cache_dir() / "machine_axes" / digest
        where.mkdir(parents=True, exist_ok=True)
        files[key] = where / f"axis_{key.lower()}.yaml"
        if not files[key].exists() or files[key].read_text() != text:
            tmp = files[key].with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(text)
            os.replace(tmp, files[key])  # a parallel run never reads half a file
    return files


@dataclass(frozen=True, kw_only=True)
class NodeRunOptions:
    """The run's options that reach the nodes beyond the program, bag and pace."""

    no_gcode: bool = False  # no G-code node: the commands come from an external NC
    optional_stop: bool = False  # M1 pauses
    max_time_s: float | None = None  # [s] simulated at most (each sim's --max-time)
    live_url: str | None = None  # the live viewer the recorder streams to


def process_name(axis: str, role: str) -> str:
    return f"{axis.lower()}_{role}"


@dataclass(frozen=True, kw_only=True)
class NodePlan:
    """The processes of a machine run: name -> (node module role, its arguments).

    An axis file run as a one-axis machine (`axis_file`, `node_plan`) keeps the single-axis
    run's node set: its sim publishes `/clock` (the ROS sim-time topic) instead of
    `<namespace>/clock`, the G-code node commands the twin_axis only, the controller runs in
    a process of its own, the recorder where `ros.recorder_host` says (`recorder_with`), the
    processes are named by role (`sim`, `controller`, `gcode`, `recorder`) and their nodes
    notice a lost peer by its heartbeat (no `stop_on_failure`)."""

    machine: str
    axes: tuple[str, ...]  # simulated NC axes, in the NC's order
    command_axes: tuple[str, ...]  # NC axes without nodes (rotary axes, those left out)
    files: dict[str, Path]  # simulated axis -> its config file
    controller_processes: str = DEFAULT_CONTROLLER_LAYOUT  # CONTROLLER_LAYOUTS
    command_batch: bool = True  # setpoints packed from the G-code node to the controllers
    axis_file: bool = False  # an axis YAML as a one-axis machine (class docstring)
    recorder_with: str = "gcode"  # RECORDER_PLACES: the process the recorder runs in

    def __post_init__(self) -> None:
        if self.recorder_with not in RECORDER_PLACES:
            raise ValueError(
                f"recorder_with = {self.recorder_with!r}: must be one of "
                f"{', '.join(RECORDER_PLACES)}"
            )

    def process_name(self, axis: str, role: str) -> str:
        """`<axis>_<role>`; an axis file's processes by role alone (`sim`, as before)."""
        return role if self.axis_file else process_name(axis, role)

    def processes(
        self,
        *,
        program: Path | None,
        bag: Path,
        realtime: bool,
        common: list[str],
        options: NodeRunOptions | None = None,
    ) -> dict[str, list[tuple[str, list[str]]]]:
        """Process name -> its nodes (role, arguments); `common`: arguments every node takes
        (timeouts; a machine's peer timeout is added here). A machine's G-code node runs inside
        the recorder's process (one DDS participant, feed_twin/ros/host.py): its commands
        reach the recorder by a function call instead of a datagram each, and the process is
        stopped last."""
        options = options or NodeRunOptions()
        if program is None and not options.no_gcode:
            raise ValueError("a node set needs a PROGRAM (or --no-gcode)")
        first, others = self.axes[0], self.axes[1:]
        if not self.axis_file:
            common = [*common, "--peer-timeout", str(PEER_TIMEOUT_S)]
        clock = [] if self.axis_file else ["--axis-clock"]
        axis_roles = ("controller", "sim")
        shared = [
            "--machine-axes", ",".join(a.lower() for a in others),
            "--command-axes", ",".join(a.lower() for a in self.command_axes),
        ]  # fmt: skip
        front = ("recorder",) if options.no_gcode else ("recorder", "gcode")
        everyone = [*front, *axis_roles]
        everyone += [f"{a.lower()}/{r}" for a in others for r in axis_roles]
        batch = ["--command-batch"] if self.command_batch and not options.no_gcode else []
        recorder = ["--bag", str(bag)]
        recorder += ["--live-url", options.live_url] if options.live_url else []
        gcode = ["--program", str(program), "--autostart", *clock, *batch]
        gcode += ["--optional-stop"] if options.optional_stop else []
        front_nodes: dict[str, tuple[str, list[str]]] = {}
        for role, extra in (("recorder", recorder), ("gcode", gcode))[: len(front)]:
            peers = ",".join(p for p in everyone if p != role)
            front_nodes[role] = (role, ["--config", str(self.files[first]), "--peers", peers,
                                        *common, *shared, *extra])  # fmt: skip
        sim_extra = [*clock, *(["--realtime"] if realtime else [])]
        if options.max_time_s is not None:
            sim_extra += ["--max-time", str(options.max_time_s)]
        place = self._recorder_place(realtime)
        out = self._front(front_nodes, place)
        for axis in self.axes:
            nodes = {}
            for role in axis_roles:
                peers = ",".join(p for p in (*front, *axis_roles) if p != role)
                extra = {"sim": sim_extra, "controller": batch}[role]
                argv = ["--config", str(self.files[axis]), "--peers", peers, *common]
                nodes[role] = (role, argv + extra)
            if self.controller_processes == "shared":
                out.setdefault(CONTROLLER_PROCESS, []).append(nodes["controller"])
            elif self.controller_processes == "per_axis":
                out[self.process_name(axis, "controller")] = [nodes["controller"]]
            # with_sim: the sim first (the run's clock and timing are its process's first node)
            with_sim = [nodes["controller"]] if self.controller_processes == "with_sim" else []
            beside = [front_nodes["recorder"]] if place == "sim" and axis == first else []
            out[self.process_name(axis, "sim")] = [nodes["sim"], *with_sim, *beside]
        if self.axis_file and GCODE_PROCESS in out:  # started last, as the axis run did
            out[GCODE_PROCESS] = out.pop(GCODE_PROCESS)
        return out

    def _recorder_place(self, realtime: bool) -> str:
        """Where the recorder runs; an axis file's `auto`: in the sim's process in lockstep,
        its own in real time (the sim must not wait for bag writing)."""
        if self.recorder_with == "auto":
            return "own" if realtime else "sim"
        return self.recorder_with

    @staticmethod
    def _front(
        nodes: dict[str, tuple[str, list[str]]], place: str
    ) -> dict[str, list[tuple[str, list[str]]]]:
        """The recorder's and the G-code node's processes (the recorder in the first sim's
        process is added there by `processes`)."""
        recorder, gcode = nodes["recorder"], nodes.get("gcode")
        if place == "gcode" and gcode is not None:
            return {RECORDER_PROCESS: [recorder, gcode]}
        out = {} if place == "sim" else {RECORDER_PROCESS: [recorder]}
        return out | ({GCODE_PROCESS: [gcode]} if gcode is not None else {})

    def axes_of_process(self, name: str) -> tuple[str, ...]:
        """The NC axes whose nodes run in process `name` (none: the G-code node and recorder)."""
        if name == CONTROLLER_PROCESS and self.controller_processes == "shared":
            return self.axes
        axis = axis_of_process(name, self.axes)
        return () if axis is None else (axis,)


def node_plan(
    machine: MachineConfig, directory: Path | None = None, *, settle_s: float | None = None
) -> NodePlan:
    """Write the axis files and plan the processes (ConfigError before anything starts). An
    axis file's nodes read the file itself (its ros.settle_s; `settle_s` is the machine
    file's)."""
    if machine.axis_file:
        return _axis_file_plan(machine)
    files = write_axis_files(machine, directory, settle_s=settle_s)
    layout, command_batch = machine_settings(machine)
    return NodePlan(
        machine=machine.name,
        axes=tuple(machine.axes),
        command_axes=tuple(a for a in machine.nc.axis_names if a not in machine.axes),
        files=files,
        controller_processes=layout,
        command_batch=command_batch,
    )


def _axis_file_plan(machine: MachineConfig) -> NodePlan:
    """An axis file's one-axis machine (NodePlan's docstring): its nodes read the file as it is
    (a file of the same text elsewhere would compile the plant's kernel again,
    write_documents)."""
    from feed_twin.nodeset.config import load_node_set_config

    return NodePlan(
        machine=machine.name,
        axes=tuple(machine.axes),
        command_axes=(),
        files={axis: Path(machine.source) for axis in machine.axes},
        controller_processes="per_axis",
        command_batch=False,
        axis_file=True,
        recorder_with=load_node_set_config(machine.source).recorder_host,
    )


def chosen_processes(
    processes: dict[str, list[tuple[str, list[str]]]], start: str | None
) -> list[str]:
    """The processes `--start` names (process names, or roles of the nodes they host), in the
    plan's order; ValueError for a name that is neither, and for roles that would start a
    process hosting a role not named (a sim and its controller under `with_sim`), since the
    other computer would start that role again."""
    names = list(processes)
    if start is None:
        return names
    wanted = [w.strip() for w in start.split(",") if w.strip()]
    roles = {n: {role for role, _ in nodes} for n, nodes in processes.items()}
    known = set(names).union(*roles.values())
    unknown = [w for w in wanted if w not in known]
    if unknown or not wanted:
        raise ValueError(
            f"--start {start}: {', '.join(unknown) or 'nothing'} is not a process or role of "
            f"this run (processes: {', '.join(names)})"
        )
    chosen = [n for n in names if n in wanted or roles[n] & set(wanted)]
    for n in chosen:
        left = sorted(roles[n] - set(wanted))
        if n not in wanted and left:
            raise ValueError(
                f"--start {start}: process {n} also runs {', '.join(left)}; name the process, "
                "or split the roles with ros.controller_processes: shared"
            )
    return chosen


def axis_of_process(name: str, axes: tuple[str, ...]) -> str | None:
    """The NC axis whose node runs in process `name` (None: the G-code node or recorder)."""
    head = name.partition("_")[0]
    return next((a for a in axes if a.lower() == head), None)


@dataclass(frozen=True, kw_only=True)
class MachineRecord:
    """Every axis's command and twin read back from a machine run's bag, on one grid."""

    axes: tuple[str, ...]  # every NC axis
    simulated: tuple[str, ...]
    t_s: np.ndarray  # (n,) [s] the states' stamps
    line: np.ndarray  # (n,) program line of the command
    command: np.ndarray  # (n, axes) [m or rad]
    command_vel: np.ndarray  # (n, axes)
    actual: np.ndarray  # (n, axes) the twins' table positions; the command elsewhere
    contour: ContourError
    # each simulated axis's AxisState.following_error over its whole recording: what its
    # drive monitored (the fine setpoint less the table), up to the exchange it tripped at
    drive_following_error: dict[str, np.ndarray] = field(default_factory=dict)

    def following_error(self, axis: str) -> np.ndarray:
        i = self.axes.index(axis)
        return self.command[:, i] - self.actual[:, i]

    def summary(self) -> dict[str, Any]:  # JSON values of several types
        out: dict[str, Any] = dict(self.contour.summary())
        out["following_error_max_m"] = {
            a.lower(): _largest(self.drive_following_error.get(a, self.following_error(a)))
            for a in self.simulated
        }
        out["simulated_s"] = float(self.t_s[-1]) if len(self.t_s) else 0.0
        out["axes"] = [a.lower() for a in self.simulated]
        return out


def _held(t_cmd: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The command in force at each time of `t` (sample-and-hold; before the first: the first)."""
    if len(t_cmd) == 0:
        return np.zeros(len(t))
    k = np.clip(np.searchsorted(t_cmd, t + 1e-12, side="right") - 1, 0, len(t_cmd) - 1)
    return values[k]


def _largest(values: np.ndarray) -> float:
    return float(np.max(np.abs(values))) if len(values) else 0.0


def read_machine_bag(bag: Path, machine: MachineConfig, segments) -> MachineRecord:
    """Commands and twins of every axis from the bag; the contour error on the states' grid
    (the common stretch of all simulated axes when one axis stopped early)."""
    from feed_twin.io.bag import BagReader

    reader = BagReader(bag)
    nc = machine.nc
    states = {
        a: reader.columns(
            AxisTopics(machine=machine.name, axis=a.lower()).state,
            ["header.stamp", "table_position", "following_error"],
        )
        for a in machine.axes
    }
    n = min(len(s["header.stamp"]) for s in states.values())
    t = states[machine.simulated[0]]["header.stamp"][:n]
    for a, s in states.items():
        if not np.allclose(s["header.stamp"][:n], t, rtol=0.0, atol=1e-9):
            raise ValueError(f"{bag}: axis {a}'s states are not on the grid of the others")
    n_axes = len(nc.axis_names)
    command, command_vel = np.zeros((n, n_axes)), np.zeros((n, n_axes))
    line = np.zeros(n, dtype=np.int64)
    fields = ["header.stamp", "position", "velocity", "line"]
    for i, a in enumerate(nc.axis_names):
        c = reader.columns(AxisTopics(machine=machine.name, axis=a.lower()).command, fields)
        command[:, i] = _held(c["header.stamp"], c["position"], t)
        command_vel[:, i] = _held(c["header.stamp"], c["velocity"], t)
        if n and len(c["header.stamp"]) and t[-1] > c["header.stamp"][-1]:
            command_vel[t > c["header.stamp"][-1], i] = 0.0  # at rest after the program
        if i == 0:
            line = _held(c["header.stamp"], c["line"], t).astype(np.int64)
    actual = command.copy()
    for a, s in states.items():
        actual[:, nc.axis_index(a)] = s["table_position"][:n]
    contour = contour_error(t, line, actual, command, command_vel, segments, n_linear=len(nc.axes))
    return MachineRecord(
        axes=nc.axis_names,
        simulated=machine.simulated,
        t_s=t,
        line=line,
        command=command,
        command_vel=command_vel,
        actual=actual,
        contour=contour,
        drive_following_error={a: s["following_error"] for a, s in states.items()},
    )
