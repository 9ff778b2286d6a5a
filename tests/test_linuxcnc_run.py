"""LinuxCNC itself (not a mock): one program run headless, every servo period received, faults.

Each run starts and stops a real LinuxCNC 2.9 (about 3 s start-up and shutdown included), so the
file keeps to one run per behaviour. tools/setup.sh installs LinuxCNC and the clock component.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from feed_twin.linuxcnc.check import linuxcnc_rejects
from feed_twin.linuxcnc.host import (
    USER_ENV,
    LinuxcncError,
    check_installed,
    host_lock,
    leftover_processes,
    leftovers,
)
from feed_twin.linuxcnc.machine import machine_for_config, write_machine
from feed_twin.linuxcnc.runner import LinuxcncRun, RunOptions, run_program

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "axis_default.yaml"
PROGRAMS = REPO / "tests" / "fixtures" / "linuxcnc"
NC, SERVO = machine_for_config(CONFIG)


def _assert_clean() -> None:
    assert leftovers() == []


def _listening_ports() -> set[int]:
    """TCP ports in LISTEN state on any address (IPv4 and IPv6)."""
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            if state == "0A":
                ports.add(int(local.rsplit(":", 1)[1], 16))
    return ports


def test_every_servo_period_of_a_program_in_si_units() -> None:
    said: list[str] = []
    listening: list[set[int]] = []

    def on_rows(rows: np.ndarray) -> None:
        if not listening:
            listening.append(_listening_ports())

    result = run_program(
        PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO, say=said.append, on_rows=on_rows
    )
    _assert_clean()
    # linuxcncsvr serves the NML channels to no other host (linuxcnc.nml's TCP=5005 is dropped)
    assert 5005 not in listening[0]
    full = result.trace
    T = SERVO.servo_period_s
    assert full.samples_lost == 0
    assert result.overruns == 0
    assert np.array_equal(full.tick, np.arange(full.samples))
    assert full.t_s == pytest.approx(full.tick * T, abs=0.0)
    # the servo thread's own clock: consecutive periods started about 1 ms apart on average
    assert np.mean(np.diff(full.tick_time_s)) == pytest.approx(T, rel=0.05)

    trace = full.cut(full.program_span())
    x, y, z = trace.pos_cmd_m.T
    # G54 = (0.4, 0.25, 0.3) m: X-50..50 mm is machine 0.35..0.45 m; Y0 -> 0.25, Z0 -> 0.3
    assert x[-1] == pytest.approx(0.35, abs=1e-9)
    # the reversal at X50 is a corner: G64 P0.01 lets the blend stay up to 10 um short of it
    assert 0.45 - NC.path_tolerance_m <= x.max() <= 0.45
    assert y[-1] == pytest.approx(0.25, abs=1e-9)
    assert z[-1] == pytest.approx(0.30, abs=1e-9)
    # F3000 = 50 mm/s, reached with at most a_max = 3 m/s^2 (LinuxCNC's plan is trapezoidal)
    v = trace.vel_cmd_m_s[:, 0]
    feeds = np.isin(trace.program_line, [4, 5])  # the G1 lines (3 is the rapid)
    assert np.abs(v[feeds]).max() == pytest.approx(0.05, rel=1e-9)
    assert np.abs(trace.acc_cmd_m_s2[:, 0]).max() <= 3.0 + 1e-9
    # velocity = the position's slope over a period (mean of the period's end velocities),
    # exact while the acceleration is constant over the period; where it changes inside one
    # (a segment joint) the mean may be off by at most a_max * T / 2
    miss = np.abs(np.diff(x) / T - 0.5 * (v[1:] + v[:-1]))
    assert np.all(miss <= 0.5 * 3.0 * T)
    assert np.mean(miss < 1e-9) > 0.99
    # 100 mm at 50 mm/s twice, each with a ramp of v/a: t = 2 (L/v + v/a) plus the rapid before
    feed_time = 2 * (0.1 / 0.05 + 0.05 / 3.0)
    assert feed_time < trace.program_time_s < feed_time + 0.6

    # The HAL servo reproduced from the recorded command. In period k LinuxCNC reads the
    # feedback the plant left in period k-1 (joint.N.pos-fb), its following error is the
    # previous command minus that, the PID output FF1 * vel-cmd + P * f-error; the drive is a
    # sampled first-order lag, the motor an integrator, and their position is the feedback of
    # period k+1. Equal to float precision: every period is there, in order, in one unit.
    cmd, fb = full.pos_cmd_m[:, 0], full.pos_fb_m[:, 0]
    start = full.program_span().start
    fe = full.f_error_m[start:, 0]
    assert fe == pytest.approx(cmd[start - 1 : -1] - fb[start:], abs=1e-12)
    u = SERVO.velocity_ff * full.vel_cmd_m_s[start:, 0] + SERVO.Kv_1_s * fe
    assert full.pid_output_m_s[start:, 0] == pytest.approx(u, abs=1e-12)
    g = SERVO.lowpass_gain
    drive = (fb[start] - fb[start - 1]) / T
    position = fb[start]
    simulated = []
    for uk in u[:-1]:
        drive += g * (uk - drive)
        position += drive * T
        simulated.append(position)
    assert np.array(simulated) == pytest.approx(fb[start + 1 :], abs=1e-9)
    # a real following error: the drive lag makes it grow with the acceleration
    assert 1e-5 < np.abs(trace.f_error_m[:, 0]).max() < 1e-3
    # nobody else held the host lock (on a loaded host the reader may lag a second: said once)
    assert [line for line in said if not line.startswith("the bridge is behind")] == [], said


def test_a_program_linuxcnc_rejects_names_message_and_line() -> None:
    rejection = linuxcnc_rejects(PROGRAMS / "rejected.ngc", NC, SERVO)
    assert rejection is not None and rejection.line == 4
    with pytest.raises(LinuxcncError) as caught:
        run_program(PROGRAMS / "rejected.ngc", nc=NC, servo=SERVO)
    assert str(caught.value) == (
        f"{PROGRAMS / 'rejected.ngc'}:4: LinuxCNC rejects 'G1 X20 G12.7': Unknown g code used"
    )
    assert "\n" not in str(caught.value)
    assert linuxcnc_rejects(PROGRAMS / "x_line.ngc", NC, SERVO) is None


def test_an_ini_that_does_not_load(tmp_path: Path) -> None:
    write_machine(tmp_path, NC, SERVO)
    hal = tmp_path / "machine.hal"
    lines = hal.read_text().splitlines()
    hal.write_text("\n".join([*lines[:115], "net broken no-such-component.0.pin"]) + "\n")
    t0 = time.monotonic()
    with pytest.raises(LinuxcncError) as caught:
        run_program(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO,
                    options=RunOptions(machine_dir=tmp_path))  # fmt: skip
    message = str(caught.value)
    assert message == (
        "LinuxCNC did not start: machine.hal:116: Pin 'no-such-component.0.pin' does not exist"
    )
    assert "\n" not in message
    assert time.monotonic() - t0 < 20.0
    _assert_clean()


def _rtapi_app_pid() -> int:
    return next(pid for pid, name in leftover_processes() if name == "rtapi_app")


def test_linuxcnc_dying_mid_run_stops_within_a_second() -> None:
    killed: list[float] = []
    received: list[int] = []

    def on_rows(rows: np.ndarray) -> None:
        received.append(len(rows))
        if sum(received) > 1500 and not killed:
            os.kill(_rtapi_app_pid(), signal.SIGKILL)
            killed.append(time.monotonic())

    run = LinuxcncRun(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO)
    with pytest.raises(LinuxcncError) as caught, run:
        while not run.ended:
            on_rows(run.poll(0.01))
    returned = time.monotonic()
    message = str(caught.value)
    assert message.startswith(
        "LinuxCNC died mid-run: its realtime process rtapi_app is gone (last tick "
    )
    assert "program line " in message
    # noticed within a poll or two; the rest is killed, not waited for
    assert run.fault_wall is not None and run.fault_wall - killed[0] < 1.0
    assert returned - killed[0] < 5.0
    _assert_clean()


def _pid_of(name: str) -> int:
    return next(pid for pid, found in leftover_processes() if found == name)


def _signal_mid_run(name: str, sig: signal.Signals) -> tuple[str, float]:
    """Send `sig` to LinuxCNC's process `name` after 1000 periods; the run's one-line fault and
    the seconds from the signal to the fault."""
    sent: list[float] = []
    run = LinuxcncRun(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO)
    with pytest.raises(LinuxcncError) as caught, run:
        while not run.ended:
            run.poll(0.01)
            if not sent and len(run.rows_so_far()) > 1000:
                os.kill(_pid_of(name), sig)
                sent.append(time.monotonic())
    assert run.fault_wall is not None
    return str(caught.value), run.fault_wall - sent[0]


@pytest.mark.slow
def test_a_dead_task_process_ends_the_run_within_a_second() -> None:
    # SIGKILL of milltask leaves the servo thread running: idle periods would stream forever
    message, noticed_s = _signal_mid_run("milltask", signal.SIGKILL)
    assert message.startswith(
        "LinuxCNC died mid-run: its task process milltask is gone (last tick "
    )
    assert "\n" not in message
    assert noticed_s < 1.0
    # nothing left: rtapi_app, io, linuxcncsvr, the NML segments and their semaphores
    _assert_clean()


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="runs LinuxCNC as a second user: root only")
def test_a_run_as_another_user_works_after_a_killed_run_as_the_first(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a killed run leaves its NML semaphores (mode 0700): remove_leftovers removes them too
    other = "feedtwin-other"
    if subprocess.run(["id", other], capture_output=True).returncode != 0:
        subprocess.run(
            ["useradd", "--system", "--create-home", "--home-dir", f"/var/lib/{other}",
             "--shell", "/usr/sbin/nologin", other],
            check=True, capture_output=True,
        )  # fmt: skip
    message, _ = _signal_mid_run("io", signal.SIGKILL)
    assert message.startswith("LinuxCNC died mid-run: its I/O controller process io is gone")
    _assert_clean()
    monkeypatch.setenv(USER_ENV, other)
    result = run_program(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO)
    assert result.trace.samples_lost == 0
    assert result.trace.samples > 4000  # the whole program: 4.1 s of feed and a rapid
    _assert_clean()


@pytest.mark.slow
def test_linuxcnc_alive_but_silent_is_stopped_after_stall_s() -> None:
    # SIGSTOP freezes the servo thread: every process lives, no period comes
    message, noticed_s = _signal_mid_run("rtapi_app", signal.SIGSTOP)
    assert message.startswith("LinuxCNC stopped mid-run: no servo period for 3.0 s (last tick ")
    assert 3.0 <= noticed_s < 4.0
    _assert_clean()


def test_a_bridge_that_falls_behind_is_said_once_and_the_run_goes_on() -> None:
    stalled: list[float] = []
    said: list[str] = []

    def on_rows(rows: np.ndarray) -> None:
        if not stalled and rows[-1, 0] > 0:
            stalled.append(time.monotonic())
            time.sleep(1.5)  # a consumer that stops reading for longer than max_lag_s

    result = run_program(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO, on_rows=on_rows,
                         say=said.append, options=RunOptions(max_lag_s=1.0))  # fmt: skip
    assert len(said) == 1
    assert said[0].startswith("the bridge is behind LinuxCNC: servo tick ")
    assert said[0].endswith("ms late (bound 1000 ms); the run goes on, every period is kept")
    assert result.trace.samples_lost == 0
    assert result.trace.program_time_s > 4.0  # the whole program
    _assert_clean()


@pytest.mark.slow
def test_a_bridge_behind_by_more_than_the_fifo_holds_is_stopped() -> None:
    def on_rows(rows: np.ndarray) -> None:
        if rows[-1, 0] > 0:
            time.sleep(1.5)  # never catches up

    with pytest.raises(LinuxcncError) as caught:
        run_program(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO, on_rows=on_rows,
                    say=lambda text: None,
                    options=RunOptions(max_lag_s=0.2, lag_limit_s=1.0))  # fmt: skip
    message = str(caught.value)
    assert message.startswith("the bridge fell behind: servo tick ")
    assert message.endswith("s late (limit 1.0 s: LinuxCNC's sampler FIFO would overflow)")
    _assert_clean()


def test_a_second_caller_waits_for_the_host_lock() -> None:
    order: list[str] = []
    said: list[str] = []
    first_in = threading.Event()
    release = threading.Event()

    def first() -> None:
        with host_lock(lambda message: None):  # (another run on the host may hold it)
            order.append("first in")
            first_in.set()
            release.wait(5.0)
            order.append("first out")

    holder = threading.Thread(target=first)
    holder.start()
    first_in.wait(5.0)
    waiter = threading.Thread(target=lambda: _second(said, order))
    waiter.start()
    time.sleep(0.3)
    assert order == ["first in"]
    release.set()
    holder.join(5.0)
    waiter.join(5.0)
    assert order == ["first in", "first out", "second in"]
    assert len(said) == 1
    assert said[0].startswith("waiting for another LinuxCNC run on this host (pid ")
    assert said[0].endswith("; lock /tmp/feed_twin-linuxcnc.lock)")


def _second(said: list[str], order: list[str]) -> None:
    with host_lock(said.append):
        order.append("second in")


def test_missing_linuxcnc_is_one_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(
        LinuxcncError, match=r"^LinuxCNC is not installed \(no 'linuxcnc' on PATH\)"
    ):
        check_installed()
    with pytest.raises(LinuxcncError, match="LinuxCNC is not installed"):
        run_program(PROGRAMS / "x_line.ngc", nc=NC, servo=SERVO)


def test_a_program_only_one_interpreter_accepts_is_named_either_way() -> None:
    from feed_twin.linuxcnc.summary import sides_disagree

    sinumerik = REPO / "tests" / "fixtures" / "gcode" / "sinumerik_style.ngc"
    assert sides_disagree(sinumerik, CONFIG) == (
        f"feed_twin's interpreter accepts the program but {sinumerik}:2: LinuxCNC rejects "
        "'N10 G71 G17 G90 G54 G64': G7x.x  requires a Q word; nothing was started"
    )
    said = sides_disagree(PROGRAMS / "params.ngc", CONFIG)
    assert said is not None, "the two interpreters disagree on params.ngc"
    assert said.startswith("LinuxCNC accepts the program but feed_twin's interpreter rejects it: ")
    assert sides_disagree(PROGRAMS / "x_line.ngc", CONFIG) is None
