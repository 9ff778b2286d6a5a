"""Across hosts: the axes' sim nodes in one network namespace, the G-code, controller and
recorder nodes in another, joined by a veth pair with discovery limited to that link
(feed_twin/ros/netns.py, dds.peers_profile); every axis equals its in-process exchanges, as on
one host (tests/test_machine_nodes.py), to 1e-9 m, and the namespaces are gone afterwards."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from test_machine_nodes import MACHINE, PROGRAM, in_process_positions, machine_file

from feed_twin.io.bag import BagReader
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.nodes import write_axis_files
from feed_twin.nodeset.auth import KEY_FILE_ENV, new_key, write_key_file
from feed_twin.nodeset.wire import NS_PER_S
from feed_twin.ros.domain import reserve_domain_id
from feed_twin.ros.netns import linked_namespaces


def _can_make_namespaces() -> bool:
    """Root with iproute2 and CAP_NET_ADMIN (a container may lack it)."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        return False
    name = f"ftprobe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, timeout=30)
    subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
    return made.returncode == 0


pytestmark = [
    pytest.mark.ros,
    pytest.mark.slow,
    pytest.mark.skipif(not _can_make_namespaces(), reason="needs root, iproute2, CAP_NET_ADMIN"),
]


def _namespaces() -> set[str]:
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=30)
    return {line.split()[0] for line in listed.stdout.splitlines() if line.strip()}


def test_axis_nodes_on_another_host_give_the_same_exchanges(tmp_path):
    program = tmp_path / "helix.ngc"
    program.write_text(PROGRAM)
    before = _namespaces()
    # the controllers on the NC's side: out of the sims' processes
    shared = machine_file(tmp_path, controller_processes="shared")
    with reserve_domain_id() as domain, linked_namespaces("ft", tmp_path) as (axes, nc):
        # the two computers share the run's key through a file only its owner reads
        write_key_file(tmp_path / "run.key", new_key())
        base = {**os.environ, KEY_FILE_ENV: str(tmp_path / "run.key")}
        argv = [
            sys.executable, "-m", "feed_twin.cli", "run", str(program), "--config", str(shared),
            "--domain-id", str(domain.domain_id), "--json",
        ]  # fmt: skip
        procs = {
            side: subprocess.Popen(
                ns.command(
                    [*argv, "--out", str(tmp_path / side), "--name", "m", "--start", start]
                ),  # fmt: skip
                env=ns.env(base),
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for side, ns, start in (
                ("axes", axes, "sim"),
                ("nc", nc, "gcode,controller,recorder"),
            )  # fmt: skip
        }
        outputs = {}
        try:
            for side, proc in procs.items():
                outputs[side] = proc.communicate(timeout=300)
        finally:
            for proc in procs.values():
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate(timeout=10)
        during = _namespaces()
    assert {axes.namespace, nc.namespace} <= during
    assert _namespaces() == before  # cleaned up
    for side, (_, err) in outputs.items():
        assert procs[side].returncode == 0, f"{side}: {err}"
    records = {side: json.loads(out.strip().splitlines()[-1]) for side, (out, _) in outputs.items()}
    assert sorted(records["axes"]["processes"]) == ["x_sim", "y_sim", "z_sim"]
    assert records["nc"]["bag"] is not None and records["axes"]["bag"] is None
    reader = BagReader(records["nc"]["bag"])
    files = write_axis_files(load_machine_config(MACHINE), settle_s=0.2)
    for axis in ("x", "y", "z"):
        state = reader.columns(f"/cnc/{axis}/state", ["header.stamp", "table_position"])
        stamps = np.round(state["header.stamp"] * NS_PER_S).astype(np.int64)
        np.testing.assert_array_equal(stamps, np.arange(len(stamps)) * 1_000_000)
        expected = in_process_positions(files[axis.upper()], program, stamps)
        np.testing.assert_allclose(
            state["table_position"], expected, rtol=0.0, atol=1e-9, err_msg=axis
        )
    assert records["nc"]["contour_error_max_m"] > 0.0


def test_the_namespaces_go_when_the_body_fails(tmp_path):
    before = _namespaces()
    with pytest.raises(RuntimeError, match="inside"), linked_namespaces("fu", tmp_path) as (a, b):
        assert a.namespace in _namespaces() and b.namespace in _namespaces()
        route = subprocess.run(
            a.command(["ip", "route", "get", b.address]), capture_output=True, text=True, timeout=30
        )
        assert "dev fuva" in route.stdout, route.stdout  # the link, not loopback
        raise RuntimeError("inside")
    assert _namespaces() == before
