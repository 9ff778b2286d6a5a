"""DDS and process set-up shared by the feed_twin nodes: the Fast DDS profile, QoS, scheduling.

- Transport and writers: `init_context` points Fast DDS at `fastdds_profiles.xml` (or its
  loopback twin when discovery is limited to this host; unless the user named a profile): UDP
  only, because a node killed while holding the lock of a shared-memory port froze every node
  that sent to it for 1-2 s, and periodic heartbeats instead of one piggybacked on every sample,
  which saves a fifth of the CPU of a lockstep exchange (see the file).
- Scheduling (`apply_scheduling`): a lockstep exchange is a ping-pong between the sim and the
  controller process, and on a virtual machine a wake-up across cores costs several times one on
  the same core, so `ros.exchange_cpu` pins both to one CPU (measured: both on one CPU beat one
  each). In real-time mode `ros.realtime_priority` runs both under SCHED_FIFO, which bounds the
  lateness by the kernel's wake-up latency instead of by whatever else the machine runs; the
  G-code node, whose setpoints the controller waits for, runs one priority below them
  (feed_twin.nodeset.pacing.setpoint_priority). Both
  apply to every thread of the process (the DDS receive threads deliver the messages); where
  the OS refuses (no CAP_SYS_NICE, no such CPU) the node logs why and runs unpinned/normal.
  `ros.cpu_latency_us` (the sim node, for the whole run) asks the kernel's PM QoS
  (`/dev/cpu_dma_latency`, held open for the life of the process, as cyclictest does) to keep
  idle CPUs in states that wake within that many microseconds: at 0 an idle CPU polls instead
  of halting. On a virtual machine waking a halted CPU goes through the host, which costs a
  cross-core message several times its send (docs/performance.md). The price is an idle CPU
  that keeps spinning while a run lasts. Needs root; refused, it is logged and skipped.
- Weight beside LinuxCNC (`set_nice`, `ros.linuxcnc_nice`): the bridge and the twin (a
  machine's bridge and each of its twins, as the shadow plan passes `--nice`) run under
  normal scheduling with a lower nice value, i.e. a larger share of a busy CPU. On this 2-core
  host at load 18 both spent 2-3 times as long waiting on a run queue as running (their
  loops' traces, feed_twin/nodeset/turn_trace.py): a process that needs a tenth of a CPU at
  1 kHz gets about that as its fair share there, and any more work (a catch-up) falls behind.
  Not SCHED_FIFO: LinuxCNC's own servo thread runs under normal scheduling when it has no
  real-time rights, and a real-time twin catching up would stall it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

FASTDDS_PROFILES = Path(__file__).with_name("fastdds_profiles.xml")
FASTDDS_PROFILES_LOCALHOST = Path(__file__).with_name("fastdds_profiles_localhost.xml")

# Data topics: reliable and in order. Transient-local history lets a subscriber that matched a
# few milliseconds late (the recorder, usually) still receive the first messages. The depth
# (5 s at 1 kHz) is what a reliable writer keeps for a reader that falls behind: a recorder
# descheduled on a loaded machine must not lose samples (a 200-deep history did).
DATA_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Program/run state: the latest value matters, also for late joiners.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
HEARTBEAT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)


def dds_environment(env: Mapping[str, str]) -> dict[str, str | None]:
    """The variables to change in `env` (None: remove) so that this process's participant uses
    feed_twin's Fast DDS profile (UDP only; fastdds_profiles.xml says why not shared memory).

    A profile the user named (FASTRTPS_/FASTDDS_DEFAULT_PROFILES_FILE) is kept as it is. With
    discovery limited to this host, rmw_fastrtps would impose shared memory, so the range goes to
    the loopback profile and rmw is told SYSTEM_DEFAULT (the profile then decides).
    """
    ours = {str(FASTDDS_PROFILES), str(FASTDDS_PROFILES_LOCALHOST)}  # inherited from a parent
    named = {env.get(f"{v}_DEFAULT_PROFILES_FILE") for v in ("FASTRTPS", "FASTDDS")}
    if named - ours - {None, ""}:
        return {}
    scope = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper()
    local = (
        scope == "LOCALHOST"
        or env.get("ROS_LOCALHOST_ONLY") == "1"
        # a parent process that made this decision already passed it on
        or (str(FASTDDS_PROFILES_LOCALHOST) in named and scope in ("", "SYSTEM_DEFAULT"))
    )
    if not local:
        return {"FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES)}
    return {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES_LOCALHOST),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "ROS_LOCALHOST_ONLY": None,  # deprecated; rcl warns whenever it is set
    }


def init_context(args: Sequence[str] | None = None, *, domain_id: int | None = None) -> Context:
    """A fresh rclpy context without rclpy's own signal handlers (spin_nodes handles them), in
    `domain_id` (default: ROS_DOMAIN_ID's)."""
    # Fast DDS reads its default profiles when the first participant is created, rmw the
    # discovery range at every init.
    for name, value in dds_environment(os.environ).items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    context = Context()
    rclpy.init(
        args=None if args is None else list(args),
        context=context,
        domain_id=domain_id,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    return context


CPU_LATENCY_DEVICE = Path("/dev/cpu_dma_latency")
_cpu_latency_request: list[int] = []  # the open PM QoS file: the request lasts while it is open


def request_cpu_latency(latency_us: int, device: Path = CPU_LATENCY_DEVICE) -> str:
    """Ask PM QoS for idle states that wake within `latency_us` for the rest of this process's
    life (a second call replaces the first); returns a note saying what took effect or why
    not."""
    try:
        fd = os.open(device, os.O_WRONLY)
    except OSError as exc:
        return f"CPU wake-up latency {latency_us} us not requested: {device}: {exc.strerror}"
    try:
        os.write(fd, latency_us.to_bytes(4, sys.byteorder, signed=True))
    except OSError as exc:
        os.close(fd)
        return f"CPU wake-up latency {latency_us} us not requested: {device}: {exc.strerror}"
    while _cpu_latency_request:
        os.close(_cpu_latency_request.pop())
    _cpu_latency_request.append(fd)
    return f"CPU wake-up latency at most {latency_us} us (PM QoS, {device})"


def apply_scheduling(*, cpu: int = -1, priority: int = 0, cpu_latency_us: int = -1) -> list[str]:
    """Pin every thread of this process to `cpu` (-1: leave), run it under SCHED_FIFO at
    `priority` (0: leave) and request CPU wake-up latency `cpu_latency_us` (-1: leave); returns
    one note per setting, saying what took effect or why not."""
    notes: list[str] = []
    if cpu_latency_us >= 0:
        notes.append(request_cpu_latency(cpu_latency_us))
    threads = (
        [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    )
    if cpu >= 0:
        try:
            for tid in threads:
                os.sched_setaffinity(tid, {cpu})
            notes.append(f"pinned to CPU {cpu}")
        except (OSError, AttributeError) as exc:
            notes.append(f"not pinned to CPU {cpu}: {exc}")
    if priority > 0:
        try:
            for tid in threads:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            notes.append(f"SCHED_FIFO priority {priority}")
        except (OSError, AttributeError) as exc:
            notes.append(f"normal scheduling, SCHED_FIFO priority {priority} refused: {exc}")
    return notes


def set_nice(nice: int) -> list[str]:
    """Every thread of this process (and the ones it starts later) at nice `nice` (0: leave);
    one note saying what took effect or why not (a lower value needs CAP_SYS_NICE)."""
    if nice == 0:
        return []
    threads = (
        [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    )
    try:
        for tid in threads:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:
        return [f"nice {nice} refused ({exc}): normal weight"]
    return [f"nice {nice}"]


def apply_nice(node: Node, nice: int) -> None:
    """`set_nice` for the process of `node`, its note in the node's log (`scheduling: ...`)."""
    for note in set_nice(nice):
        node.get_logger().info(f"scheduling: {note}")


def raise_priority(priority: int) -> list[str]:
    """SCHED_FIFO at `priority` for every thread of this process, unless it runs at that
    priority or above already (nodes that share a process: the G-code node beside the sim in
    one process must not lower the exchange's priority); apply_scheduling's notes."""
    if priority <= 0:
        return []
    try:
        current = os.sched_getparam(0).sched_priority
        if os.sched_getscheduler(0) == os.SCHED_FIFO and current >= priority:
            return [f"SCHED_FIFO priority {current} kept (asked {priority})"]
    except (OSError, AttributeError):
        pass  # apply_scheduling says why it cannot
    return apply_scheduling(priority=priority)


def peers_profile(interface: str, peers: Sequence[str], *, participants: int = 32) -> str:
    """A Fast DDS profile (XML text) for nodes spread over several computers: UDP on the
    interface with address `interface` only, participants found by unicast at `peers` (every
    computer of the run, this one included; `participants` participant IDs per address), and
    feed_twin's writer settings (fastdds_profiles.xml). Point FASTRTPS_DEFAULT_PROFILES_FILE at
    it on each computer: the nodes then keep it (`dds_environment`)."""
    writer = FASTDDS_PROFILES.read_text()
    writer = writer[writer.index("  <data_writer") : writer.index("</profiles>")]
    locators = "".join(f"<locator><udpv4><address>{p}</address></udpv4></locator>" for p in peers)
    return f"""<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>feed_twin_udp</transport_id>
      <type>UDPv4</type>
      <maxInitialPeersRange>{participants}</maxInitialPeersRange>
      <interfaceWhiteList><address>{interface}</address></interfaceWhiteList>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="feed_twin_participant" is_default_profile="true">
    <rtps>
      <builtin>
        <initialPeersList>{locators}</initialPeersList>
      </builtin>
      <userTransports><transport_id>feed_twin_udp</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
{writer}</profiles>
"""
