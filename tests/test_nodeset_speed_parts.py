"""The node set's fast paths: fixed-layout CDR packing, scheduling settings, the full cascade's
controller configuration and the drive's mode check (no ROS graph needed)."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from typing import Any

import numpy as np
import pytest
from controller_support import current_loop
from nodes_support import AXIS_CONFIG

from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.config import NodeSetConfig, load_node_set_config
from feed_twin.nodeset.controller_core import controller_node_config
from feed_twin.nodeset.wire import MODE_CST, MODE_VOLTAGE, DriveSetpoint
from feed_twin.sim.config import load_axis_config

FEEDBACK = FlatCodec("feed_twin_msgs/msg/AxisFeedback")


def _feedback_values() -> dict:
    return {
        "header.stamp.sec": 12,
        "header.stamp.nanosec": 345_000_000,
        "axis": "X",
        "encoder_counts": -7,
        "encoder_angle": 0.25,
        "scale_position": 0.4001,
        "i_a": 1.5,
        "i_b": -0.5,
        "i_c": -1.0,
        "i_d": 0.01,
        "i_q": 1.7,
        "u_dc": 560.0,
        "u_d_ref": -1.25,
        "u_q_ref": 12.5,
        "following_error": 2e-6,
        "mode": 10,
        "status_word": 567,
        "fault_code": 0,
    }


def test_fixed_layout_packs_the_same_bytes_as_the_general_codec() -> None:
    values = _feedback_values()
    layout = FEEDBACK.fixed({"axis": "X"})
    numbers = tuple(values[n] for n in layout.numbers)
    data = layout.encode(numbers)
    assert data == FEEDBACK.encode_map(values)
    assert len(data) == layout.size
    assert layout.decode(data) == numbers
    assert layout.numbers[layout.index("i_q")] == "i_q"


def test_fixed_layout_reads_a_message_with_other_strings() -> None:
    values = _feedback_values() | {"axis": "X2", "header.frame_id": "drive"}
    layout = FEEDBACK.fixed({"axis": "X"})
    decoded = layout.decode(FEEDBACK.encode_map(values))
    assert decoded == tuple(values[n] for n in layout.numbers)


def test_fixed_layout_errors_name_the_message_and_field() -> None:
    layout = FEEDBACK.fixed({"axis": "X"})
    with pytest.raises(ValueError, match=r"AxisFeedback: 2 values given, 17 number fields"):
        layout.encode((1, 2))
    with pytest.raises(KeyError, match=r"AxisFeedback has no string field\(s\) label"):
        FEEDBACK.fixed({"label": "X"})
    with pytest.raises(KeyError, match=r"AxisFeedback has no number field 'axis'"):
        layout.index("axis")


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("exchange_cpu", -2, r"exchange_cpu = -2: must be a whole number in \[-1, 1023\]"),
        ("exchange_cpu", 1.0, r"exchange_cpu = 1.0: must be a whole number in \[-1, 1023\]"),
        ("realtime_priority", 100, r"realtime_priority = 100: must be a whole number in \[0, 99\]"),
        ("realtime_priority", True, r"realtime_priority = True: must be a whole number"),
        ("cpu_latency_us", -2, r"cpu_latency_us = -2: must be a whole number"),
        ("linuxcnc_nice", -21, r"linuxcnc_nice = -21: must be a whole number in \[-20, 19\]"),
        ("linuxcnc_nice", 0.5, r"linuxcnc_nice = 0.5: must be a whole number in \[-20, 19\]"),
        ("record_batch", -1, r"record_batch = -1: must be a whole number in \[0, 1000\]"),
        ("record_batch", 2.0, r"record_batch = 2.0: must be a whole number in \[0, 1000\]"),
        (
            "recorder_host",
            "controller",
            r"recorder_host = 'controller': must be one of auto, sim, own",
        ),
    ],
)
def test_scheduling_settings_are_checked(field: str, value: object, message: str) -> None:
    settings: dict[str, Any] = {field: value}  # a value of any type, the wrong ones included
    with pytest.raises(ValueError, match=message):
        NodeSetConfig(**settings)


def test_scheduling_that_the_os_refuses_is_reported_not_raised() -> None:
    from feed_twin.ros.dds import apply_scheduling

    assert apply_scheduling() == []  # nothing asked, nothing done
    notes = apply_scheduling(cpu=1023)  # no machine here has 1024 CPUs
    assert len(notes) == 1 and notes[0].startswith("not pinned to CPU 1023: ")


NICE_PROBE = """
import os, sys, threading
from feed_twin.ros.dds import set_nice
print(set_nice(0))
before = threading.Thread(target=threading.Event().wait, args=(5,), daemon=True)
before.start()
print(set_nice(int(sys.argv[1]))[0])
seen = {int(t): os.getpriority(os.PRIO_PROCESS, int(t)) for t in os.listdir("/proc/self/task")}
later = threading.Thread(target=lambda: print(os.getpriority(os.PRIO_PROCESS, 0)))
later.start()
later.join()
print(sorted(set(seen.values())))
"""


def test_nice_applies_to_every_thread_and_a_refusal_is_said() -> None:
    """Both threads present and threads started later run at the nice value asked for; one
    that the OS refuses (a lower value without CAP_SYS_NICE) is said, not raised."""
    import subprocess

    current = os.getpriority(os.PRIO_PROCESS, 0)
    target = min(19, current + 3)  # raising the value needs no rights
    done = subprocess.run([sys.executable, "-c", NICE_PROBE, str(target)], capture_output=True,
                          text=True, check=True, timeout=60)  # fmt: skip
    assert done.stdout.split("\n")[:4] == ["[]", f"nice {target}", str(target), f"[{target}]"]
    if os.geteuid() == 0:
        return  # root may lower it: nothing to refuse
    refused = subprocess.run([sys.executable, "-c", NICE_PROBE, "-20"], capture_output=True,
                             text=True, timeout=60)  # fmt: skip
    assert "nice -20 refused (" in refused.stdout


def test_the_setpoint_stream_runs_one_priority_below_the_announced_exchange() -> None:
    from feed_twin.nodeset.pacing import (
        announced_priority,
        realtime_announcement,
        setpoint_priority,
    )

    assert announced_priority(realtime_announcement(50)) == 50
    assert announced_priority(realtime_announcement(0)) == 0
    for other in ("done ok", "realtime", "realtime priority -3", "lockstep priority 50"):
        assert announced_priority(other) is None, other
    assert [setpoint_priority(p) for p in (50, 2, 1, 0)] == [49, 1, 1, 0]


RAISE_PROBE = """
import os, sys
from feed_twin.ros.dds import raise_priority
try:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
except OSError:
    sys.exit(3)
print(raise_priority(49)[0])
print(raise_priority(0))
print(os.sched_getparam(0).sched_priority)
print(raise_priority(51)[0])
print(os.sched_getparam(0).sched_priority)
"""


def test_raising_the_priority_never_lowers_a_process_that_runs_the_exchange() -> None:
    import subprocess

    # a process of its own: the test process keeps its scheduling
    done = subprocess.run(
        [sys.executable, "-c", RAISE_PROBE], capture_output=True, text=True, timeout=60
    )
    if done.returncode == 3:
        pytest.skip("SCHED_FIFO is refused here (no CAP_SYS_NICE)")
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [
        "SCHED_FIFO priority 50 kept (asked 49)",
        "[]",
        "50",
        "SCHED_FIFO priority 51",
        "51",
    ]


def test_a_cpu_latency_request_is_held_open_or_its_refusal_reported(tmp_path) -> None:
    from feed_twin.ros import dds

    missing = tmp_path / "no_such_device"
    assert dds.request_cpu_latency(0, missing) == (
        f"CPU wake-up latency 0 us not requested: {missing}: No such file or directory"
    )
    device = tmp_path / "cpu_dma_latency"  # a stand-in file: what the kernel reads is an s32
    device.write_bytes(b"")
    try:
        note = dds.request_cpu_latency(20, device)
        assert note == f"CPU wake-up latency at most 20 us (PM QoS, {device})"
        assert int.from_bytes(device.read_bytes(), sys.byteorder, signed=True) == 20
        assert len(dds._cpu_latency_request) == 1  # held open: the request lasts while it is
        dds.request_cpu_latency(0, device)
        assert len(dds._cpu_latency_request) == 1  # the second replaced the first
    finally:
        while dds._cpu_latency_request:
            os.close(dds._cpu_latency_request.pop())


def test_full_cascade_runs_the_current_loop_at_the_exchange_period() -> None:
    controller = load_axis_config(AXIS_CONFIG).controller
    derived, notes = controller_node_config(controller, 1e-3, with_current=True)
    current = current_loop(derived)
    assert current.period_s == 1e-3 and derived.base_period_s == 1e-3
    # Technical optimum for 1.5 periods of delay: Kp = L / (2 * 1.5 T), Ti = L / (R_s + R_ff),
    # R_ff = p psi_pm K_t tau_ff / J the late back-EMF feed-forward's resistance, tau_ff the
    # estimator's 1 ms (half a sample, the two-tap FIR's half) and 1.5 exchanges.
    R_ff = 4 * 0.3167 * 1.9 * 2.5e-3 / 5.8e-3
    assert current.Kp_q_V_A == pytest.approx(4.0e-3 / 3.0e-3, rel=1e-12)
    assert current.Ti_q_s == pytest.approx(4.0e-3 / (0.35 + R_ff), rel=1e-12)
    assert not derived.computation_delay and current.dead_time_comp_V == 0.0
    assert any(
        n.startswith("current loop at the exchange period")
        and "(zero on R_s + 1.04 Ohm of late back-EMF feed-forward)" in n
        for n in notes
    )
    without, _ = controller_node_config(controller, 1e-3)
    assert without.current is None
    with pytest.raises(ValueError, match=r"boundary = 'voltage': the controller has no current"):
        controller_node_config(
            dataclasses.replace(controller, current=None), 1e-3, with_current=True
        )


def test_drive_refuses_a_command_of_the_other_kind() -> None:
    from feed_twin.ros.sim_node import build_drive_host

    ros = load_node_set_config(AXIS_CONFIG)
    host = build_drive_host(AXIS_CONFIG, ros)
    assert host.setpoint.mode == MODE_CST and not host.modulator
    with pytest.raises(ValueError, match=r"mode = -1: this drive takes modes 8, 9, 10"):
        host.advance(DriveSetpoint(t_ns=0, mode=MODE_VOLTAGE, enable=True))
    modulator = build_drive_host(AXIS_CONFIG, dataclasses.replace(ros, boundary="voltage"))
    assert modulator.modulator and modulator.setpoint.mode == MODE_VOLTAGE
    with pytest.raises(ValueError, match=r"mode = 10: this drive takes only MODE_VOLTAGE"):
        modulator.advance(DriveSetpoint(t_ns=0, mode=MODE_CST, enable=True))
    # Zero voltage while enabled: duties 1/2, stage on; the truth is at rest at the start.
    t_ns, row = modulator.advance(None)
    truth = modulator.truth(row)
    assert t_ns == 0 and math.isclose(truth[1], 0.4, abs_tol=1e-12)
    assert np.isfinite(truth).all()


def test_pacing_report_figures() -> None:
    from feed_twin.nodeset.pacing import pacing_report

    lockstep = pacing_report(steps=4000, period_s=1e-3, wall_s=2.0)
    assert lockstep == {
        "steps": 4000,
        "sim_time_s": 4.0,
        "wall_time_s": 2.0,
        "realtime_factor": 2.0,
    }
    assert pacing_report(steps=0, period_s=1e-3, wall_s=0.0)["realtime_factor"] is None
    # 100 steps 0.1 ms late and one 3 ms late: p50 0.1 ms, max 3 ms, one step beyond a period.
    late = [1e-4] * 100 + [3e-3]
    report = pacing_report(steps=101, period_s=1e-3, wall_s=0.101, lateness_s=late)
    assert report["lateness_p50_ms"] == pytest.approx(0.1)
    assert report["lateness_max_ms"] == pytest.approx(3.0)
    assert report["missed_steps"] == 1
    given = pacing_report(steps=1, period_s=1e-3, wall_s=1.0, lateness_s=[], missed_steps=7)
    p99 = given["lateness_p99_ms"]
    assert isinstance(p99, float) and math.isnan(p99) and given["missed_steps"] == 7
