"""LinuxCNC's own servo loop closed on the twin: a whole program on a LinuxCNC machine
(feed_twin.linuxcnc) with the HAL component in place of the simulated X joint."""

from __future__ import annotations

from native_support import ROOT

from feed_twin.cli import main as cli_main
from feed_twin.native.linuxcnc_loop import figures, run, twin_machine

AXIS = ROOT / "config" / "axis_default.yaml"
PROGRAM = ROOT / "tests" / "fixtures" / "gcode" / "square_metric_abs.ngc"


def test_a_program_runs_with_the_twin_in_the_servo_loop(tmp_path):
    args = ["hal", "--config", str(AXIS), "--out", str(tmp_path / "hal"), "--install"]
    assert cli_main(args) == 0
    machine = tmp_path / "machine"
    nc, servo = twin_machine(AXIS, machine)
    hal = (machine / "machine.hal").read_text()
    assert "net x-twin-fb feed-twin-axis.pos-fb => joint.0.motor-pos-fb" in hal
    result = run(PROGRAM, nc, servo, machine)
    got = figures(result, 0)
    assert got.samples_lost == 0 and got.overruns == 0
    assert got.periods > 4000  # the 4.7 s program, every 1 ms servo period recorded
    # the twin's drive follows LinuxCNC's command with full feed-forward: micrometres, far
    # inside LinuxCNC's FERROR (2 mm) and the drive's own limit (2 mm)
    assert got.f_error_max_m < 50e-6


def test_linuxcnc_pid_closes_the_position_loop_through_the_twins_current_input(tmp_path):
    # torque boundary: LinuxCNC's pid (PD at 25 Hz, acceleration feed-forward) drives the q
    # current of the twin's drive, whose scale is the joint's feedback
    args = ["hal", "--config", str(AXIS), "--out", str(tmp_path / "hal"), "--mode", "torque"]
    assert cli_main([*args, "--install"]) == 0
    machine = tmp_path / "machine"
    nc, servo = twin_machine(AXIS, machine, boundary="torque")
    hal = (machine / "machine.hal").read_text()
    assert "net x-output => feed-twin-axis.current-cmd" in hal
    result = run(PROGRAM, nc, servo, machine)
    got = figures(result, 0)
    assert got.samples_lost == 0 and got.overruns == 0
    # a PD loop without integral: friction leaves an error of its current over Pgain, inside
    # LinuxCNC's FERROR of 2 mm
    assert got.f_error_max_m < 1e-3
