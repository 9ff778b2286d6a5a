"""LinuxCNC with its simple HAL plant vs LinuxCNC closed over the twin (virtual commissioning).

Runs one program twice on the real LinuxCNC: with the HAL servo (pid -> drive lag -> integrator)
and with the twin's axis as the X drive (velocity boundary, feedback one servo period late,
feed_twin.linuxcnc.commissioning). Prints per run the following error LinuxCNC sees on X (max,
RMS over the program), the servo periods missed (commissioning: the twin's answer came after its
period), the servo thread's period jitter, start lateness histogram and late periods (its own
clock, feed_twin.linuxcnc.period_timing) and the reader's latency. Last line: one JSON object.

    .venv/bin/python benchmarks/linuxcnc_commissioning.py [PROGRAM]

The machine has no PREEMPT_RT kernel: LinuxCNC's threads run SCHED_OTHER ("POSIX
non-realtime"), so late periods are caught up back to back, and the twin, in another process
that must answer each period within the period, misses some.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from feed_twin.linuxcnc.commissioning import run_virtual_commissioning
from feed_twin.linuxcnc.machine import machine_for_config
from feed_twin.linuxcnc.runner import run_program
from feed_twin.linuxcnc.samples import ServoTrace

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "axis_default.yaml"
PROGRAM = REPO / "tests" / "fixtures" / "linuxcnc" / "x_line.ngc"


def _figures(trace: ServoTrace) -> dict:
    span = trace.program_span()
    fe = trace.f_error_m[span, 0]
    period = np.diff(trace.tick_time_s[span]) * 1e3
    reader = trace.reader_latency_s[span] * 1e3
    timing = trace.cut(span).period_timing()
    return {
        "periods": timing.periods,
        "late_periods": timing.late_periods,
        "start_lateness_p50_ms": timing.lateness_p50_ms,
        "start_lateness_p99_ms": timing.lateness_p99_ms,
        "start_lateness_max_ms": timing.lateness_max_ms,
        "start_lateness_histogram": list(timing.histogram),
        "program_time_s": trace.program_time_s,
        "fe_max_um": float(np.max(np.abs(fe)) * 1e6),
        "fe_rms_um": float(np.sqrt(np.mean(fe * fe)) * 1e6),
        "samples_lost": trace.samples_lost,
        "period_p99_ms": float(np.percentile(period, 99)),
        "period_max_ms": float(period.max()),
        "reader_latency_p50_ms": float(np.percentile(reader, 50)),
        "reader_latency_p99_ms": float(np.percentile(reader, 99)),
    }


def main() -> None:
    program = Path(sys.argv[1]) if len(sys.argv) > 1 else PROGRAM
    nc, servo = machine_for_config(CONFIG)
    plain = _figures(run_program(program, nc=nc, servo=servo).trace)
    vc = run_virtual_commissioning(program, CONFIG)
    twin = _figures(vc.trace)
    twin["missed_periods"] = vc.missed_periods
    twin["program_periods"] = vc.program_periods
    twin["missed_share"] = vc.missed_periods / max(1, vc.program_periods)
    for name, f in (("HAL plant", plain), ("twin (commissioning)", twin)):
        missed = (
            f"missed {f['missed_periods']} of {f['program_periods']} periods, "
            if "missed_periods" in f
            else ""
        )
        print(
            f"{name:22s} program {f['program_time_s']:.3f} s, X following error max "
            f"{f['fe_max_um']:.1f} um RMS {f['fe_rms_um']:.1f} um, {missed}servo period p99 "
            f"{f['period_p99_ms']:.2f} ms max {f['period_max_ms']:.1f} ms; {f['periods']} ticks, "
            f"{f['late_periods']} started > 1 period late (lateness p99 "
            f"{f['start_lateness_p99_ms']:.2f} ms, histogram {f['start_lateness_histogram']})"
        )
    print(
        json.dumps(
            {
                "program": program.name,
                "load_1min": os.getloadavg()[0],
                **{f"hal_{k}": v for k, v in plain.items()},
                **{f"twin_{k}": v for k, v in twin.items()},
            }
        )
    )


if __name__ == "__main__":
    main()
