"""The machine's shadow twin as ROS nodes, planned in plain Python; its figures from the bag.

Per simulated axis two processes in the axis's namespace `/<machine>/<axis>`:

- a stand-in node (feed_twin/ros/standin_node.py `--follow --axis-clock`): that axis of the
  "real machine", the axis model with its `shadow.standin` hidden effects, answering each NC
  sample of the G-code node with a measured sample on `<ns>/joint_states` (position and effort,
  as ros2_control's joint_state_broadcaster publishes them) and publishing `<ns>/clock`;
- a twin node (feed_twin/ros/twin_node.py): the shadow twin of that axis, reading
  `<ns>/command` and `<ns>/joint_states` through the axis's column map and publishing
  `<ns>/twin/state`, `<ns>/twin/residual` and `<ns>/twin/health`.

The G-code node commands every NC axis and the recorder records every axis into one bag; both
live in one process, in the first axis's namespace, as in the machine run
(feed_twin.machine.nodes, whose axis files these extend by the axis's `shadow:` section). A
real multi-axis machine would replace the stand-ins: it publishes the same topics per axis.

An axis file's shadow run is its one-axis machine's (`ShadowPlan.axis_file`), planned as the
single-axis run had it: its nodes read the axis file as it is (no written copy, so its plant's
kernel is the one already compiled), the stand-in publishes `/clock` (the ROS sim-time topic),
every node runs in a process of its own named by its role (`recorder`, `twin`, `standin`,
`gcode`; with LinuxCNC `recorder`, `twin`, `linuxcnc`: the single-axis bridge,
feed_twin/ros/linuxcnc_node.py), the nodes notice a lost peer by its heartbeat, the column map
is `<run>_map.yaml` and the dashboard `<run>.rrd`, and `--realtime` paces the stand-in.

Lockstep across axes: each stand-in plays a sample as soon as its command is there and at most
a window ahead of its twin's output, and the G-code node publishes at most `ros.lookahead`
periods ahead of the slowest axis's clock. Each axis's stand-in and twin see exactly the
samples of the in-process machine shadow (feed_twin.machine.shadow), so both give the same
figures per axis (`read_shadow_bag` and `AxisShadow.summary` share `axis_figures`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.core.config import ConfigError
from feed_twin.machine.config import MachineConfig
from feed_twin.machine.nodes import PEER_TIMEOUT_S, axis_documents, process_name, write_documents
from feed_twin.machine.shadow import axis_figures, axis_shadow_config
from feed_twin.nodeset.roles import node_role
from feed_twin.nodeset.topics import AxisTopics

RECORDER_PROCESS = "recorder"  # hosts the recorder (and the G-code node beside stand-ins)
LINUXCNC_PROCESS = "linuxcnc"
TWIN = node_role("twin")


def shadow_documents(machine: MachineConfig) -> dict[str, dict[str, Any]]:
    """NC axis -> the single-axis config its stand-in and twin read (the machine run's axis
    document and the axis's `shadow:` section); ConfigError (one line) for an axis without a
    usable shadow section."""
    docs = axis_documents(machine)
    nc_period = machine.nc.interpolation_period_s
    for axis, doc in docs.items():
        shadow = axis_shadow_config(machine, axis)
        check_shadow_period(machine.axes[axis].source, shadow.sample_period_s, nc_period)
        doc["shadow"] = machine.axes[axis].shadow
    return docs


def check_shadow_period(source: str | Path, sample_period_s: float, nc_period_s: float) -> None:
    """ConfigError (one line, naming `source`) unless the shadow samples at the NC's period."""
    if abs(sample_period_s - nc_period_s) > 1e-12:
        raise ConfigError(
            f"{source}: shadow.sample_period_s = {sample_period_s!r}: must equal "
            f"nc.interpolation_period_s = {nc_period_s!r} (the twin shadows the NC's command "
            "stream)"
        )


@dataclass(frozen=True, kw_only=True)
class ShadowPlan:
    """The processes of a machine's shadow run: name -> (node role, its arguments)."""

    machine: str
    source: str  # the machine file
    axes: tuple[str, ...]  # simulated NC axes, in the NC's order
    command_axes: tuple[str, ...]  # NC axes without nodes (rotary axes, those left out)
    files: dict[str, Path]  # simulated axis -> its config file
    maps: dict[str, Path]  # simulated axis -> the column map of its topics (the twin reads it)
    effort_units: dict[str, str]  # simulated axis -> the unit of its twin's effort (N, N m, A)
    period_s: float  # [s] the NC's interpolation period: one stand-in sample each
    linuxcnc: bool  # LinuxCNC is the machine (feed_twin/ros/machine_linuxcnc_node.py)
    axis_file: bool = False  # an axis YAML as a one-axis machine (module docstring)
    ros_axis: str = ""  # an axis file's ros.axis: its nodes' namespace /<machine>/<ros_axis>
    # ros.linuxcnc_nice of the first axis's file (an axis file's own, a machine's from its ros:
    # section): the nice value of LinuxCNC's bridge and of every twin beside it
    # (feed_twin/ros/dds.py, set_nice) [-]
    linuxcnc_nice: int = 0

    def namespace(self, axis: str) -> str:
        return f"/{self.machine}/{self.ros_axis if self.axis_file else axis.lower()}"

    def rrd(self, bag: Path, axis: str) -> Path:
        """The shadow dashboard the axis's twin writes (an axis file's: `<run>.rrd`)."""
        if self.axis_file:
            return bag.with_name(f"{bag.name}.rrd")
        return bag.with_name(f"{bag.name}_{axis.lower()}.rrd")

    @property
    def axis_roles(self) -> tuple[str, ...]:
        return ("twin",) if self.linuxcnc else ("standin", "twin")

    @property
    def beside_linuxcnc(self) -> list[str]:
        """The arguments of the bridge and of each twin beside LinuxCNC: a larger share of a
        busy CPU (ros.linuxcnc_nice; LinuxCNC, started by the bridge, inherits it)."""
        return ["--nice", str(self.linuxcnc_nice)] if self.linuxcnc else []

    def processes(
        self,
        *,
        program: Path,
        bag: Path,
        common: list[str],
        live_url: str | None = None,
        realtime: bool = False,
        optional_stop: bool = False,
    ) -> dict[str, list[tuple[str, list[str]]]]:
        """Process name -> its nodes (role of feed_twin.nodeset.roles, arguments); `common`: the
        timeouts every node takes (the peer timeout is added here); `live_url`: the live viewer
        every twin streams its dashboard to (each axis's a recording of its own); `realtime`:
        the stand-in paces by the wall clock (an axis file's only: a machine's axes run in
        lockstep); `optional_stop`: M1 pauses."""
        if self.axis_file:
            return self._axis_file_processes(
                program=program, bag=bag, common=common, live_url=live_url, realtime=realtime,
                optional_stop=optional_stop,
            )  # fmt: skip
        first, others = self.axes[0], self.axes[1:]
        common = [*common, "--peer-timeout", str(PEER_TIMEOUT_S)]
        served = [
            "--machine-axes", ",".join(a.lower() for a in others),
            "--command-axes", ",".join(a.lower() for a in self.command_axes),
        ]  # fmt: skip
        hub = {
            "recorder": [*served, "--bag", str(bag),
                         "--twin-namespace", f"{self.namespace(first)}/twin"],
            "gcode": [*served, "--program", str(program), "--autostart", "--axis-clock",
                      *(["--optional-stop"] if optional_stop else [])],
            "linuxcnc": ["--machine-config", self.source, "--axes", ",".join(self.axes),
                         "--program", str(program), *self.beside_linuxcnc],
        }  # fmt: skip
        hub_roles = ("recorder", "linuxcnc") if self.linuxcnc else ("recorder", "gcode")
        everyone = [*hub_roles, *self.axis_roles]
        everyone += [f"{a.lower()}/{r}" for a in others for r in self.axis_roles]
        out: dict[str, list[tuple[str, list[str]]]] = {RECORDER_PROCESS: []}
        for role in hub_roles:
            peers = ",".join(p for p in everyone if p != role)
            argv = ["--config", str(self.files[first]), "--peers", peers, *common, *hub[role]]
            # beside stand-ins the G-code node shares the recorder's process (the machine run's
            # layout); LinuxCNC's bridge has its own
            if role == "linuxcnc":  # the registry's role of the machine's LinuxCNC bridge
                out[LINUXCNC_PROCESS] = [("machine_linuxcnc", argv)]
            else:
                out.setdefault(RECORDER_PROCESS, []).append((role, argv))
        for axis in self.axes:
            for role in self.axis_roles:
                mates = (*hub_roles, *self.axis_roles)
                peers = ",".join(p for p in mates if p != role)
                argv = ["--config", str(self.files[axis]), "--peers", peers, *common]
                if role == "standin":
                    argv += ["--follow", "--axis-clock", "--period", repr(self.period_s)]
                else:
                    argv += ["--map", str(self.maps[axis]), "--machine", self.machine,
                             "--axis", axis.lower(), "--rrd", str(self.rrd(bag, axis))]  # fmt: skip
                    argv += ["--rerun-url", live_url] if live_url else []
                    if self.linuxcnc:  # the bridge sends its periods packed (linuxcnc_node)
                        topics = AxisTopics(machine=self.machine, axis=axis.lower())
                        argv += ["--batch-topic", topics.bridge_batch, *self.beside_linuxcnc]
                out[process_name(axis, role)] = [(role, argv)]
        return out

    def _axis_file_processes(
        self,
        *,
        program: Path,
        bag: Path,
        common: list[str],
        live_url: str | None,
        realtime: bool,
        optional_stop: bool,
    ) -> dict[str, list[tuple[str, list[str]]]]:
        """An axis file's processes (module docstring): each node in its own, named by its role,
        in start order; the arguments of the single-axis run."""
        (axis,) = self.axes
        machine = ["--machine", self.machine, "--axis", self.ros_axis]
        topics = AxisTopics(machine=self.machine, axis=self.ros_axis)
        nice = self.beside_linuxcnc
        own = {
            "recorder": ["--bag", str(bag), "--twin-namespace", f"{topics.namespace}/twin"],
            "twin": ["--map", str(self.maps[axis]), *machine, "--rrd", str(self.rrd(bag, axis)),
                     *(["--batch-topic", topics.bridge_batch, *nice] if self.linuxcnc else []),
                     *(["--rerun-url", live_url] if live_url else [])],
            "standin": ["--follow", *machine, *(["--realtime"] if realtime else [])],
            "gcode": ["--program", str(program), "--autostart",
                      *(["--optional-stop"] if optional_stop else [])],
            "linuxcnc": ["--program", str(program), *nice],
        }  # fmt: skip
        roles = ("recorder", "twin", "linuxcnc") if self.linuxcnc else tuple(own)[:4]
        out: dict[str, list[tuple[str, list[str]]]] = {}
        for role in roles:
            peers = ",".join(r for r in roles if r != role)
            argv = ["--config", str(self.files[axis]), "--peers", peers, *common, *own[role]]
            out[role] = [(role, argv)]
        return out


def shadow_plan(machine: MachineConfig, bag: Path, *, linuxcnc: bool = False) -> ShadowPlan:
    """Write the axis files and the column maps (`<bag>_map_<axis>.yaml`; an axis file's nodes
    read the file itself, its map is `<bag>_map.yaml`) and plan the processes (ConfigError
    before anything starts). With `linuxcnc` the machine reports no effort and its rapids reach
    the axis velocity limit (as the single-axis LinuxCNC run)."""
    from feed_twin.analysis.twin import ModelDoc, Twin
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.shadow.standin import write_map

    if machine.axis_file:
        files = {axis: Path(machine.source) for axis in machine.axes}
    else:
        files = write_documents(machine, shadow_documents(machine), None)
    # the bridge reads the first axis's file too (machine_linuxcnc_node --config)
    ros = load_node_set_config(next(iter(files.values())))
    ros_axis = ros.axis if machine.axis_file else ""
    bag.parent.mkdir(parents=True, exist_ok=True)
    maps, units = {}, {}
    for axis, path in files.items():
        nc_axis = machine.nc.axes[machine.nc.axis_index(axis)]
        twin = Twin.compile(ModelDoc.load(path))
        units[axis] = twin.effort_unit
        suffix = "" if machine.axis_file else f"_{axis.lower()}"
        maps[axis] = write_map(
            bag.with_name(f"{bag.name}_map{suffix}.yaml"),
            twin,
            f"/{machine.name}/{ros_axis or axis.lower()}",
            travel_m=nc_axis.travel_max_m - nc_axis.travel_min_m,
            with_effort=not linuxcnc,
            max_speed_m_s=1.5 * nc_axis.rapid_m_s if linuxcnc else 0.5,
        )
    return ShadowPlan(
        machine=machine.name,
        source=machine.source,
        axes=tuple(machine.axes),
        command_axes=tuple(a for a in machine.nc.axis_names if a not in machine.axes),
        files=files,
        maps=maps,
        effort_units=units,
        period_s=machine.nc.interpolation_period_s,
        linuxcnc=linuxcnc,
        axis_file=machine.axis_file,
        ros_axis=ros_axis,
        linuxcnc_nice=ros.linuxcnc_nice,
    )


RESIDUAL_FIELDS = (
    "header.stamp",
    "following_error_measured",
    "following_error_twin",
    "following_error_deviation",
    "effort_deviation",
)


def read_shadow_bag(
    bag: Path, machine: str, axes: tuple[str, ...], effort_units: dict[str, str]
) -> dict[str, dict[str, Any]]:
    """Per axis (lower case) the shadow figures from the twins' residual and health topics of
    the bag (`axis_figures`, as in-process) plus the paired samples and the largest measured
    following error; ValueError when an axis's twin shadowed nothing."""
    from feed_twin.io.bag import BagReader

    reader = BagReader(bag)
    present = {t.name for t in reader.info.topics if t.message_count > 0}
    out = {}
    for axis in axes:
        twin = f"/{machine}/{axis.lower()}/twin"
        residual, health = TWIN.topic(twin, "residual"), TWIN.topic(twin, "health")
        if residual not in present:
            raise ValueError(f"axis {axis}: the bag has no {residual}: nothing was shadowed")
        r = reader.columns(residual, RESIDUAL_FIELDS)
        h = {"header.stamp": np.zeros(0), "level": np.zeros(0), "effect": [], "message": []}
        if health in present:
            h = reader.columns(health, ("header.stamp", "level", "effect", "message"))
        figures = axis_figures(
            fe_dev_m=r["following_error_deviation"],
            effort_dev=r["effort_deviation"],
            twin_ok=np.isfinite(r["following_error_twin"]),
            verdict_t_s=np.asarray(h["header.stamp"], dtype=float),
            verdict_level=np.asarray(h["level"], dtype=np.int64),
            verdict_effect=[str(e) for e in h["effect"]],
            verdict_message=[str(m) for m in h["message"]],
            effort_unit=effort_units[axis],
        )
        fe = r["following_error_measured"]
        fe = fe[np.isfinite(fe)]
        figures["samples"] = int(len(r["header.stamp"]))
        figures["following_error_max_m"] = float(np.max(np.abs(fe))) if fe.size else None
        out[axis.lower()] = figures
    return out
