"""The twin as a LinuxCNC realtime HAL component, in a bare `halrun` (LinuxCNC's own threads).

A 1 ms servo thread runs a sine position command (siggen, with its velocity and acceleration
as feed-forward), the component and a sampler, for 3 s. Every call steps exactly 16 base ticks
(the `ticks` pin advances by 16 in every sampled period: no period missed or doubled), and the
feedback equals the numba engine's, driven by the sampled commands: the same plant and drive
computed in LinuxCNC's thread. A thread of another period is refused with a message in the log.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from native_support import ROOT

from feed_twin.cli import main as cli_main
from feed_twin.control.layout import build_cascade, with_mode
from feed_twin.core import signals
from feed_twin.linuxcnc.period_timing import period_timing
from feed_twin.native.build import CModel, compile_kernel
from feed_twin.native.emit import c_kernel
from feed_twin.native.hal import HalcompileMissingError, find_halcompile
from feed_twin.native.halrun import hal_session, sine_loop
from feed_twin.sim.config import build_engine, load_axis_config

AXIS = ROOT / "config" / "axis_default.yaml"
N_SAMPLES = 3000  # servo periods of 1 ms
OFFSET = 400.0  # [mm] the sine's centre; 10 mm amplitude at 1 Hz


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The component of axis_default for a 1 ms servo period, in LinuxCNC's module directory."""
    out = tmp_path_factory.mktemp("hal")
    assert os.geteuid() == 0, "installing a HAL component into /usr/lib/linuxcnc needs root"
    args = ["hal", "--config", str(AXIS), "--out", str(out), "--servo-period", "1e-3", "--install"]
    assert cli_main(args) == 0
    return out


def test_servo_thread_steps_the_twin_one_period_per_call_as_the_engine(installed):
    run = sine_loop(N_SAMPLES, offset=OFFSET)
    pos_cmd, vel_cmd, acc_cmd = run["pos_cmd"], run["vel_cmd"], run["acc_cmd"]
    pos_fb, fe = run["pos_fb"], run["following_error"]
    period_error, ticks, fault = run["period_error"], run["ticks"], run["fault"]
    assert not period_error.any() and not fault.any()
    # one call per servo period, 16 base ticks each, none missed: 16, 32, 48, ...
    assert np.array_equal(ticks, 16.0 * np.arange(1, N_SAMPLES + 1))
    # the thread's own clock beside it: one tick a period, 1 ms apart on average (late periods
    # are caught up back to back), every period in the lateness histogram
    assert np.array_equal(np.diff(run["clock_tick"]), np.ones(N_SAMPLES - 1))
    timing = period_timing(run["clock_tick"], run["clock_time_s"], period_s=1e-3)
    assert np.mean(np.diff(run["clock_time_s"])) == pytest.approx(1e-3, rel=0.05)
    assert sum(timing.histogram) == timing.periods == N_SAMPLES
    # the sine starts at full speed (63 mm/s from rest): the drive catches up within its 2 mm
    # limit, then follows with full feed-forward within 10 um (the reversals: friction)
    assert np.abs(fe).max() < 0.5
    assert np.abs(fe[500:]).max() < 0.01
    # the engine driven by the sampled commands (printed to 1e-6 mm) gives the same feedback
    axis = load_axis_config(AXIS)
    engine = build_engine(axis, output_period_s=axis.engine.base_period_s)
    engine.reset(x0=axis.plant.initial_state({"table": 1.0}) * (OFFSET / 1000.0))
    ref = np.zeros((16 * N_SAMPLES, signals.REF_SIZE))
    for slot, values in ((signals.REF_POS_M, pos_cmd), (signals.REF_VEL_M_S, vel_cmd)):
        ref[:, slot] = np.repeat(values / 1000.0, 16)
    ref[:, signals.REF_ACC_M_S2] = np.repeat(acc_cmd / 1000.0, 16)
    result = engine.advance(len(ref), ref=ref)
    expected = result["meas.x_scale_m"][15::16] * 1000.0
    assert np.abs(pos_fb - expected).max() < 1e-4  # [mm]: 0.1 um


def test_a_thread_of_another_period_is_refused_with_a_message_in_the_log(installed):
    script = """
loadrt threads name1=servo-thread period1=500000
loadrt feed_twin_axis
addf feed-twin-axis servo-thread
start
loadusr -w sleep 0.3
show pin feed-twin-axis.period-error
show pin feed-twin-axis.ticks
stop
"""
    with hal_session(script) as (log, _):
        pass
    assert (
        "feed_twin_axis: thread period 500000 ns, but built for a servo period of 1000000 ns "
        "(16 ticks of 62500 ns): not stepping (rebuild with feed-twin hal --servo-period)"
    ) in log
    assert log.count("feed_twin_axis: thread period") == 1  # said once, not every period
    pins = {line.split()[-1]: line.split()[-2] for line in log.splitlines() if "feed-twin" in line}
    assert pins["feed-twin-axis.period-error"] == "TRUE"
    assert pins["feed-twin-axis.ticks"] == "0"


def test_missing_halcompile_names_the_debian_package():
    with pytest.raises(
        HalcompileMissingError,
        match=r"^no `no-halcompile` on the PATH: install "
        r"the Debian package linuxcnc-uspace-dev \(apt-get install "
        r"linuxcnc-uspace-dev; tools/setup.sh does as root\)$",
    ):
        find_halcompile("no-halcompile")


TORQUE = """
loadrt threads name1=servo-thread period1=1000000
loadrt feed_twin_axis_cst
loadrt sampler depth=2000 cfg=ffs
addf feed-twin-axis-cst servo-thread
addf sampler.0 servo-thread
setp feed-twin-axis-cst.start-pos 400
setp feed-twin-axis-cst.current-cmd 2.0
net fb feed-twin-axis-cst.pos-fb => sampler.0.pin.0
net iq feed-twin-axis-cst.current-q => sampler.0.pin.1
net ticks feed-twin-axis-cst.ticks => sampler.0.pin.2
start
loadusr -w sh sample.sh
stop
"""


def test_at_a_torque_boundary_the_current_command_pin_drives_the_twin_as_the_engine(tmp_path):
    # the pin LinuxCNC's PID output drives (as q-current setpoint): 2 A held for 0.3 s
    args = ["hal", "--config", str(AXIS), "--out", str(tmp_path), "--mode", "torque"]
    assert cli_main([*args, "--module", "feed_twin_axis_cst", "--install"]) == 0
    n = 300
    with hal_session(TORQUE, files={"sample.sh": f"halsampler -n {n} > s.txt\n"}) as (log, d):
        assert (d / "s.txt").exists(), log
        rows = np.loadtxt(d / "s.txt")
    pos_fb, i_q, ticks = rows[:, 0], rows[:, 1], rows[:, 2]
    assert np.array_equal(ticks, 16.0 * np.arange(1, n + 1))
    assert np.all(i_q == 2.0)
    # the C kernel of the same torque-boundary drive in this process (equal to the numba
    # engine's, tests/test_native_kernel.py; its numba kernel would compile for 12 s here)
    axis = load_axis_config(AXIS)
    cascade = with_mode(build_cascade(axis.controller), "torque")
    kernel = c_kernel(
        axis.plant,
        base_period_s=axis.engine.base_period_s,
        controller=cascade,
        seed=axis.engine.seed,
    )
    model = CModel(compile_kernel(kernel), kernel)
    model.set_states(axis.plant.initial_state({"table": 1.0}) * 0.4)
    ref = np.zeros((16 * n, signals.REF_SIZE))
    ref[:, signals.REF_I_Q_EXT_A] = 2.0
    rows = model.run(len(ref), ref=ref)
    scale = kernel.record_names.index("meas.x_scale_m")
    expected = rows[15::16, scale] * 1000.0
    assert np.abs(pos_fb - expected).max() < 1e-5  # [mm]: the samples are printed to 1 nm
    assert pos_fb[-1] - pos_fb[0] > 30.0  # [mm] it accelerated
