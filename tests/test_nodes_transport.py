"""The nodes' DDS transport: UDP only, so that a killed node cannot freeze the others.

A node killed while holding the lock of its Fast DDS shared-memory port froze every node that
sent to it for 1-2 s (fastdds_profiles.xml says how); the kill tests in test_nodes_faults.py and
test_shadow_run.py check the consequence, these check the cause is configured away.
"""

from __future__ import annotations

import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import rclpy
from nodes_support import node_env
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import String

from feed_twin.ros.dds import (
    DATA_QOS,
    FASTDDS_PROFILES,
    FASTDDS_PROFILES_LOCALHOST,
    dds_environment,
    init_context,
)
from feed_twin.ros.domain import reserve_domain_id
from feed_twin.ros.runtime import FeedTwinNode, NodeOptions


def test_host_only_discovery_goes_to_the_loopback_profile() -> None:
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "5"}
    assert dds_environment(env) == {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES_LOCALHOST),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
        "ROS_LOCALHOST_ONLY": None,
    }
    assert dds_environment({"ROS_LOCALHOST_ONLY": "1"})["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(
        FASTDDS_PROFILES_LOCALHOST
    )


def test_network_discovery_uses_the_udp_profile_and_a_user_profile_is_kept() -> None:
    assert dds_environment({}) == {"FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES)}
    assert dds_environment({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) == {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES)
    }
    mine = {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/my_dds.xml", "ROS_LOCALHOST_ONLY": "1"}
    assert dds_environment(mine) == {}
    # our own file inherited from a parent process is not a user's choice: decided again
    inherited = {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(FASTDDS_PROFILES),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    assert dds_environment(inherited)["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(
        FASTDDS_PROFILES_LOCALHOST
    )


def _writer_times(path) -> dict[str, float]:
    ns = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    times = ET.parse(path).getroot().find("p:data_writer/p:times", ns)
    assert times is not None, f"{path}: no data_writer/times"

    def field(child: ET.Element, name: str) -> int:
        found = child.find(f"p:{name}", ns)
        assert found is not None and found.text is not None, f"{path}: {child.tag} has no {name}"
        return int(found.text)

    return {
        child.tag.split("}")[1]: field(child, "sec") + field(child, "nanosec") * 1e-9
        for child in times
    }


def test_writers_repair_losses_at_the_next_heartbeat_without_an_event_per_sample() -> None:
    """Both profiles: periodic heartbeats, and a NACK-suppression window that is not zero (a
    zero window woke the event thread for every sample to every reader) but shorter than the
    heartbeat period, so a lost sample is still repaired at the next heartbeat."""
    for path in (FASTDDS_PROFILES, FASTDDS_PROFILES_LOCALHOST):
        times = _writer_times(path)
        assert times == _writer_times(FASTDDS_PROFILES), path
        assert 0.0 < times["nackSupressionDuration"] < times["heartbeatPeriod"] <= 0.5, times


PROBE = """
import glob, os, time
import rclpy
from std_msgs.msg import String
from feed_twin.ros.dds import init_context
context = init_context()
node = rclpy.create_node("probe", context=context)
node.create_publisher(String, "probe", 10)
time.sleep(0.3)
names = {open(p).read().strip() for p in glob.glob(f"/proc/{os.getpid()}/task/*/comm")}
print(" ".join(sorted(n for n in names if n.startswith("dds."))))
"""


def test_a_node_process_on_a_host_only_graph_runs_no_shared_memory_transport() -> None:
    with reserve_domain_id() as domain:
        out = subprocess.run(
            [sys.executable, "-c", PROBE],
            env=node_env(domain.domain_id),
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        ).stdout.split()
    assert any(n.startswith("dds.udp") for n in out), out  # Fast DDS names its threads so
    assert not any(n.startswith("dds.shm") for n in out), out


def test_a_child_of_a_host_only_process_stays_host_only() -> None:
    parent = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    applied = {k: v for k, v in dds_environment(parent).items() if v is not None}
    assert dds_environment(applied)["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(
        FASTDDS_PROFILES_LOCALHOST
    )


def test_a_node_beats_only_once_the_recorder_listens_to_its_outputs() -> None:
    """The twin's first heartbeat (which lets the stand-in start the run) waits for the
    recorder's readers: a run stopped a second after its start once lost all the twin's output
    to a recorder that matched the twin's writers only after the twin had gone."""
    context = init_context()
    nodes = []
    try:
        options = NodeOptions(machine="cnc", axis="x", peers=("recorder",))
        node = FeedTwinNode("twin", options, context=context)
        nodes.append(node)
        pub = node.create_publisher(String, "/cnc/x/twin/residual", DATA_QOS)
        node.start_heartbeat(when=lambda: node.recorder_listens([pub]))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def spin(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end and not node.liveness.beating:
                executor.spin_once(timeout_sec=0.05)

        spin(0.5)
        assert not node.liveness.beating
        recorder = rclpy.create_node("recorder_data", namespace="/cnc/x", context=context)
        nodes.append(recorder)
        recorder.create_subscription(String, "/cnc/x/twin/residual", lambda m: None, DATA_QOS)
        spin(5.0)
        assert node.liveness.beating
        # without a recorder among the peers there is nothing to wait for
        alone = FeedTwinNode(
            "gcode", NodeOptions(machine="cnc", axis="x", peers=()), context=context
        )
        nodes.append(alone)
        assert alone.recorder_listens([pub])
    finally:
        for n in nodes:
            if isinstance(n, FeedTwinNode):
                n.liveness.stop()
            n.destroy_node()
        context.try_shutdown()


def test_a_node_whose_outputs_the_recorder_never_takes_says_so() -> None:
    context = init_context()
    node = None
    try:
        options = NodeOptions(machine="cnc", axis="x", peers=("recorder",), startup_timeout_s=0.3)
        node = FeedTwinNode("sim", options, context=context)
        pub = node.create_publisher(String, "/cnc/x/state_probe", DATA_QOS)
        node.start_heartbeat(when=lambda: node.recorder_listens([pub]))
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and not node.done:
            executor.spin_once(timeout_sec=0.05)
        assert node.done and not node.liveness.beating
        assert "recorder did not subscribe to this node's data topics within 0.3 s" in (
            node.exit_message
        )
    finally:
        if node is not None:
            node.liveness.stop()
            node.destroy_node()
        context.try_shutdown()
