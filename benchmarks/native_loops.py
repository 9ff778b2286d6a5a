"""The twin in other tools' loops: FMPy simulating the FMU, LinuxCNC's servo thread running the
HAL component.

Figures (last printed line, one JSON object):
- fmu_max_state_deviation: largest |FMPy's state - the engine's state| over every state and
  output point (1 ms) of tests/fixtures/gcode/sample.ngc (7.1 s) through the FMU of
  config/axis_default.yaml (FMPy feeds the NC samples as inputs, 1 ms steps), relative to each
  state's range (fmu_max_table_deviation_m: the table position's, in metres);
  fmu_realtime_factor: simulated seconds per wall second of that FMPy run (FMPy's Python loop
  calls the FMU once per millisecond).
- hal_*: the HAL component of config/axis_default.yaml (1 ms servo period, 16 ticks of 62.5 us
  per call) in a bare halrun, a 10 mm / 1 Hz sine position command with velocity and
  acceleration feed-forward, HAL_SECONDS long: the drive's following error (max after the first
  0.5 s, RMS), the calls in which the component did not advance exactly 16 ticks
  (hal_step_errors, 0 by construction: it counts a defect of the component, not the host), the
  servo thread's own timing from the feedtwin_clock component first in the thread (start
  lateness p50/p99/max and histogram, interval p50/p99/max, hal_late_periods: periods that
  started more than one period after their deadline; feed_twin.linuxcnc.period_timing), and
  the component's execution time per call (LinuxCNC's `time` pin in CPU clocks, divided by the
  clock rate /proc/cpuinfo states: median, p99, max).
- linuxcnc_*: sample.ngc on a whole LinuxCNC machine (feed_twin.linuxcnc, 1 ms servo thread),
  once with LinuxCNC's simulated X joint (PID, drive lowpass, integrator) and once with the HAL
  component closing X's loop instead: LinuxCNC's following error of X over the program
  (joint.0.f-error: max and RMS, um) and the servo periods lost (the thread's tick counter) and
  sampler overruns of each run; linuxcnc_twin_pid_*: the same with the component at the torque
  boundary, LinuxCNC's pid (PD at 25 Hz with acceleration feed-forward, no integral) closing the
  position loop through the twin's q-current input.

    .venv/bin/python benchmarks/native_loops.py      (as root: installs the HAL component)
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from feed_twin.core import signals
from feed_twin.linuxcnc.period_timing import EDGES_MS, period_timing
from feed_twin.native.fmu import build_fmu
from feed_twin.native.hal import halcompile, write_comp
from feed_twin.native.halrun import sine_loop
from feed_twin.native.program import program_ref
from feed_twin.sim.config import build_engine, load_axis_config

ROOT = Path(__file__).resolve().parent.parent
AXIS = ROOT / "config" / "axis_default.yaml"
SAMPLE = ROOT / "tests" / "fixtures" / "gcode" / "sample.ngc"
HAL_SECONDS = 60


def fmu_figures(axis) -> dict:
    from fmpy import simulate_fmu

    h = axis.engine.base_period_s
    ref = program_ref(SAMPLE, h)
    dec = round(1e-3 / h)
    nc = ref[::dec]
    t = np.arange(len(nc)) * 1e-3
    names = ("ref.pos_ref_m", "ref.vel_ref_m_s", "ref.acc_ref_m_s2")
    inputs = np.zeros(len(nc), dtype=[("time", float)] + [(n, float) for n in names])
    inputs["time"] = t
    slots = (signals.REF_POS_M, signals.REF_VEL_M_S, signals.REF_ACC_M_S2)
    for name, slot in zip(names, slots, strict=True):
        inputs[name] = nc[:, slot]
    start = float(ref[0, signals.REF_POS_M])
    with tempfile.TemporaryDirectory() as tmp:
        fmu = build_fmu(axis, Path(tmp) / "axis.fmu")
        t0 = time.perf_counter()
        result = simulate_fmu(
            str(fmu),
            stop_time=t[-1],
            output_interval=1e-3,
            input=inputs,
            start_values={"start.table": start},
        )
        wall = time.perf_counter() - t0
    engine = build_engine(axis, output_period_s=1e-3)
    engine.reset(x0=axis.plant.initial_state({"table": 1.0}) * start)
    expected = engine.advance(len(ref), ref=ref)
    worst = 0.0
    for name in axis.plant.state_names:
        want = expected[name][: len(result)]
        span = max(np.abs(want).max(), 1e-300)
        worst = max(worst, float(np.abs(result[name] - want).max() / span))
    table = float(np.abs(result["table.s"] - expected["table.s"][: len(result)]).max())
    return {
        "fmu_max_state_deviation": worst,
        "fmu_max_table_deviation_m": table,
        "fmu_realtime_factor": round(t[-1] / wall, 2),
    }


def cpu_hz() -> float:
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("cpu MHz"):
            return float(line.split(":")[1]) * 1e6
    return float("nan")


def hal_figures(axis) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        halcompile(write_comp(axis, Path(tmp), 1e-3), install=True)
    n = HAL_SECONDS * 1000
    run = sine_loop(n)
    fe = run["following_error"]  # [mm]
    steps = np.diff(np.concatenate(([0.0], run["ticks"])))
    call_us = run["time"][10:] / cpu_hz() * 1e6
    timing = period_timing(run["clock_tick"], run["clock_time_s"], period_s=1e-3)
    return {
        "hal_periods": n,
        "hal_step_errors": int(np.count_nonzero(steps != 16)),
        "hal_late_periods": timing.late_periods,
        "hal_start_lateness_p50_ms": round(timing.lateness_p50_ms, 3),
        "hal_start_lateness_p99_ms": round(timing.lateness_p99_ms, 3),
        "hal_start_lateness_max_ms": round(timing.lateness_max_ms, 3),
        "hal_interval_p50_ms": round(timing.interval_p50_ms, 3),
        "hal_interval_p99_ms": round(timing.interval_p99_ms, 3),
        "hal_interval_max_ms": round(timing.interval_max_ms, 3),
        "hal_start_lateness_histogram": list(timing.histogram),
        "hal_start_lateness_edges_ms": list(EDGES_MS),
        "hal_faults": int(np.count_nonzero(run["fault"])),
        "hal_following_error_max_um": round(float(np.abs(fe[500:]).max()) * 1e3, 3),
        "hal_following_error_rms_um": round(float(np.sqrt(np.mean(fe[500:] ** 2))) * 1e3, 3),
        "hal_following_error_startup_um": round(float(np.abs(fe[:500]).max()) * 1e3, 1),
        "hal_call_us_median": round(float(np.median(call_us)), 2),
        "hal_call_us_p99": round(float(np.percentile(call_us, 99)), 2),
        "hal_call_us_max": round(float(call_us.max()), 2),
    }


def linuxcnc_figures() -> dict:
    from feed_twin.native.linuxcnc_loop import compare_runs, figures, run, twin_machine

    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        Path(tmp).chmod(0o777)
        runs = compare_runs(SAMPLE, AXIS, Path(tmp))
        comp = write_comp(load_axis_config(AXIS), Path(tmp), 1e-3, mode="torque")
        halcompile(comp, install=True)
        machine = Path(tmp) / "machine_pid"
        nc, servo = twin_machine(AXIS, machine, boundary="torque")
        result = run(SAMPLE, nc, servo, machine)
        runs["twin_pid"] = figures(result, [a.name for a in nc.axes].index(nc.twin_axis))
    out = {}
    for name, f in runs.items():
        out[f"linuxcnc_{name}_f_error_max_um"] = round(f.f_error_max_m * 1e6, 2)
        out[f"linuxcnc_{name}_f_error_rms_um"] = round(f.f_error_rms_m * 1e6, 2)
        out[f"linuxcnc_{name}_samples_lost"] = f.samples_lost
        out[f"linuxcnc_{name}_overruns"] = f.overruns
        out[f"linuxcnc_{name}_periods"] = f.periods
    return out


def main() -> int:
    axis = load_axis_config(AXIS)
    figures = fmu_figures(axis)
    print(f"FMU through FMPy: largest state deviation {figures['fmu_max_state_deviation']:.3g}")
    figures.update(hal_figures(axis))
    print(
        f"HAL: {figures['hal_periods']} ticks, {figures['hal_step_errors']} calls that did not "
        f"advance 16 base ticks, {figures['hal_late_periods']} periods started more than one "
        f"period late (start lateness p50/p99/max {figures['hal_start_lateness_p50_ms']}/"
        f"{figures['hal_start_lateness_p99_ms']}/{figures['hal_start_lateness_max_ms']} ms, "
        f"histogram {figures['hal_start_lateness_histogram']} over {list(EDGES_MS)} ms), "
        f"following error max {figures['hal_following_error_max_um']} um"
    )
    figures.update(linuxcnc_figures())
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
