"""Private ROS domains: no two holders get the same ID, a released or dead holder's ID is free
again, the locks live in fixed host-wide directories whatever $TMPDIR says, a domain a DDS
participant already uses is skipped, and running out of IDs or asking for an invalid one says
so."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from feed_twin.ros.domain import (
    FIRST_DOMAIN_ID,
    LAST_DOMAIN_ID,
    LOCK_DIRS,
    domain_in_use,
    domain_ports,
    lock_dirs,
    private_graph_env,
    reserve_domain_id,
)

NO_SOCKETS = ()  # udp_tables: judge by the locks alone, whatever else runs on the host


def test_holders_in_one_process_get_distinct_ids(tmp_path):
    with reserve_domain_id(lock_dir=tmp_path) as a, reserve_domain_id(lock_dir=tmp_path) as b:
        assert a.domain_id != b.domain_id
        assert FIRST_DOMAIN_ID <= a.domain_id <= LAST_DOMAIN_ID
        assert FIRST_DOMAIN_ID <= b.domain_id <= LAST_DOMAIN_ID


def test_an_id_held_by_another_process_is_skipped_and_freed_when_it_dies(tmp_path):
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, pathlib; from feed_twin.ros.domain import reserve_domain_id\n"
            "r = reserve_domain_id(lock_dir=pathlib.Path(sys.argv[1]))\n"
            "print(r.domain_id, flush=True); sys.stdin.read()",
            str(tmp_path),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdout is not None, "started with stdout=PIPE"
    try:
        held = int(holder.stdout.readline())
        ours = []
        for _ in range(LAST_DOMAIN_ID - FIRST_DOMAIN_ID):
            ours.append(reserve_domain_id(lock_dir=tmp_path, udp_tables=NO_SOCKETS))
        assert held not in {r.domain_id for r in ours}
        assert len({r.domain_id for r in ours}) == len(ours)
        holder.kill()  # the kernel drops a dead process's flock
        holder.wait(timeout=30)
        with reserve_domain_id(lock_dir=tmp_path) as freed:
            assert freed.domain_id == held
        for reservation in ours:
            reservation.release()
    finally:
        holder.kill()
        holder.wait(timeout=30)


def test_running_out_of_ids_names_the_range_and_the_lock_directory(tmp_path):
    count = LAST_DOMAIN_ID - FIRST_DOMAIN_ID + 1
    held = [reserve_domain_id(lock_dir=tmp_path, udp_tables=NO_SOCKETS) for _ in range(count)]
    try:
        with pytest.raises(RuntimeError) as error:
            reserve_domain_id(lock_dir=tmp_path, udp_tables=NO_SOCKETS)
        assert str(error.value) == (
            f"all ROS domain IDs {FIRST_DOMAIN_ID}..{LAST_DOMAIN_ID} are held by other "
            f"processes (lock files feed_twin-ros-domain-*.lock in {tmp_path})"
        )
    finally:
        for reservation in held:
            reservation.release()
    with reserve_domain_id(lock_dir=tmp_path):
        pass  # released IDs are free again


def test_private_graph_env_limits_discovery_to_this_host():
    assert private_graph_env(42) == {
        "ROS_DOMAIN_ID": "42",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }


@pytest.mark.parametrize("domain_id", [0, 102])
def test_private_graph_env_rejects_an_id_outside_the_range(domain_id):
    with pytest.raises(ValueError, match=rf"^domain_id = {domain_id}: must lie in \[1, 101\]$"):
        private_graph_env(domain_id)


def test_the_test_session_runs_in_its_own_domain(ros_domain_id):
    assert os.environ["ROS_DOMAIN_ID"] == str(ros_domain_id)
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    # Another process cannot take the session's ID while the session holds it.
    lock = f"{lock_dirs()[0]}/feed_twin-ros-domain-{ros_domain_id}.lock"
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys\n"
            "fd = os.open(sys.argv[1], os.O_RDWR)\n"
            "try:\n"
            "    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
            "    print('free')\n"
            "except BlockingIOError:\n"
            "    print('held')",
            lock,
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert probe.stdout.strip() == "held", probe.stderr


def test_the_lock_directories_do_not_follow_tmpdir(tmp_path):
    """A second reservation made with another TMPDIR sees the first one's lock."""
    with reserve_domain_id() as first:
        probe = subprocess.run(
            [
                sys.executable,
                "-c",
                "from feed_twin.ros.domain import reserve_domain_id, FIRST_DOMAIN_ID, "
                "LAST_DOMAIN_ID\n"
                "got = [reserve_domain_id(udp_tables=()) for _ in "
                "range(LAST_DOMAIN_ID - FIRST_DOMAIN_ID)]\n"
                "print(' '.join(str(r.domain_id) for r in got))",
            ],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, "TMPDIR": str(tmp_path)},
        )
    taken = probe.stdout.split()
    assert str(first.domain_id) not in taken, probe.stderr
    assert list(tmp_path.iterdir()) == []
    assert lock_dirs()[0] in LOCK_DIRS


def test_a_domain_a_participant_uses_without_a_lock_is_skipped(tmp_path):
    """A ROS node started by hand (no lock) binds its ports in its domain's block."""
    probe = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, rclpy\nrclpy.init()\nn = rclpy.create_node('intruder')\n"
            "print('up', flush=True)\nsys.stdin.read()",
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, **private_graph_env(LAST_DOMAIN_ID)},
    )
    assert probe.stdout is not None, "started with stdout=PIPE"
    try:
        assert probe.stdout.readline().strip() == "up"
        assert domain_in_use(LAST_DOMAIN_ID)
        held = []
        with pytest.raises(RuntimeError, match="in use by unlocked DDS participants"):
            while True:  # until every ID is locked here or in use by someone
                held.append(reserve_domain_id(lock_dir=tmp_path))
        ids = {r.domain_id for r in held}
        for reservation in held:
            reservation.release()
    finally:
        probe.kill()
        probe.wait(timeout=30)
    assert held and LAST_DOMAIN_ID not in ids


def test_domain_ports_are_the_rtps_block():
    assert domain_ports(1) == range(7650, 7900)
    assert not domain_in_use(5, frozenset({7400 + 250 * 6, 7400 + 250 * 5 - 1}))
    assert domain_in_use(5, frozenset({7400 + 250 * 5 + 11}))
