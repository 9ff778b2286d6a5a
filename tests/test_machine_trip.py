"""Issue 29, machine runs: the summary reports the following error each drive monitored (the
state's own, up to the exchange it tripped at), and a drive fault's reason names the program
line active at its time. The bag is a machine run's, written as the node set records it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.gcode.geometry import programmed_path
from feed_twin.io.bag import BagReader
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.nodes import read_machine_bag
from feed_twin.machine.run_cli import write_machine_bag
from feed_twin.machine.simulate import simulate_machine
from feed_twin.ros.machine_run import _with_trip_line

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
PROGRAM = "G21 G90 G54\nG1 X1 F3000\nG1 Z-20 F6000\nG1 X5\nM2\n"


@pytest.fixture(scope="module")
def machine_bag(tmp_path_factory):
    work = tmp_path_factory.mktemp("trip")
    program = work / "trip.ngc"
    program.write_text(PROGRAM)
    machine = load_machine_config(MACHINE)
    run = simulate_machine(machine, program, settle_s=0.05)
    bag = write_machine_bag(run, machine, work / "bag")
    return machine, program, bag


def test_the_summary_gives_the_following_error_the_drives_monitored(machine_bag):
    machine, program, bag = machine_bag
    record = read_machine_bag(bag, machine, programmed_path(program, machine.nc))
    reader = BagReader(bag)
    for axis in machine.simulated:
        state = reader.columns(f"/cnc/{axis.lower()}/state", ["following_error"])
        expected = float(np.max(np.abs(state["following_error"])))
        assert record.summary()["following_error_max_m"][axis.lower()] == expected
    assert record.summary()["following_error_max_m"]["z"] > 1e-6  # Z moved


def test_a_drive_fault_names_its_program_line(machine_bag):
    machine, program, bag = machine_bag
    fault = (
        "axis Z: z_sim node (cnc/z) exited with code 1: drive fault 1 at t = 0.0600 s: "
        "following error 0.022 mm exceeds the limit 0.020 mm "
        "(controller.position.following_error_limit_m)"
    )
    others = "  x_sim node (cnc/x) exited with code 130: stopped by SIGTERM"
    named = _with_trip_line(f"{fault}\n{others}", bag, machine, program)
    command = BagReader(bag).columns("/cnc/z/command", ["header.stamp", "line"])
    at = int(np.searchsorted(command["header.stamp"], 0.06 + 1e-12, side="right")) - 1
    line = int(command["line"][at])
    assert line >= 2
    text = PROGRAM.splitlines()[line - 1]
    assert named == f"{fault} (program line {line}: {text})\n{others}"
    # a reason without a drive fault, or naming no axis of the machine, is left as it is
    assert _with_trip_line(others, bag, machine, program) == others
    assert _with_trip_line(fault.replace("axis Z", "axis Q"), bag, machine, program) == (
        fault.replace("axis Z", "axis Q")
    )
