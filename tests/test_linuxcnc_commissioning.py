"""Virtual commissioning on the real LinuxCNC: its PID drives the twin's axis, whose scale is
LinuxCNC's feedback one servo period later. One run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.linuxcnc.commissioning import run_virtual_commissioning
from feed_twin.linuxcnc.host import leftovers

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "axis_default.yaml"
PROGRAM = REPO / "tests" / "fixtures" / "linuxcnc" / "x_slow.ngc"


def test_linuxcnc_closes_its_servo_loop_over_the_twin() -> None:
    said: list[str] = []
    result = run_virtual_commissioning(PROGRAM, CONFIG, say=said.append)
    trace = result.trace
    assert trace.samples_lost == 0
    assert result.twin_scale_m.size == trace.samples  # the twin answered every period
    span = trace.program_span()
    cmd, fb, fe = (a[:, 0] for a in (trace.pos_cmd_m, trace.pos_fb_m, trace.f_error_m))
    x = result.twin_scale_m
    # LinuxCNC's feedback in period m is the scale the twin latched at the start of period
    # m - 1 (shifted by the offset homing set), except in the periods the twin's answer was
    # late: then LinuxCNC reused the previous feedback.
    m = np.arange(span.start, span.stop)
    offset = np.median(fb[m] - x[m - 1])
    on_time = np.abs(fb[m] - x[m - 1] - offset) < 1e-9
    held = fb[m] == fb[m - 1]
    # A value that reaches the streamer just as its period starts comes a period late: every
    # feedback is still the twin's own scale. How often that happens depends on the host's
    # load (a timing, not a property of the loop), so it is bounded loosely.
    late = np.abs(fb[m] - x[m - 2] - offset) < 1e-9
    assert np.all(on_time | held | late)
    assert np.count_nonzero(~(on_time | held)) <= max(3, m.size // 100)
    moving = np.abs(trace.vel_cmd_m_s[m, 0]) > 1e-3
    missed_in_motion = int(np.count_nonzero(~on_time & moving))
    # two counts of the missed periods: the display's late answers, and what LinuxCNC read
    assert missed_in_motion <= result.missed_periods
    assert result.missed_periods < 0.5 * result.program_periods
    # the following error is LinuxCNC's own: previous command minus this feedback
    assert fe[m] == pytest.approx(cmd[m - 1] - fb[m], abs=1e-12)
    # the twin's axis went where the program sent it (X-5 in G54 = 0.395 m): what is left at
    # the end is the P loop's decaying following error (Kv = 30 1/s), which LinuxCNC sees too
    end = trace.samples - 1
    assert abs(fe[end]) < 5e-5
    assert x[end - 1] == pytest.approx(0.395, abs=abs(fe[end]) + 1e-6)
    assert np.abs(fe[m]).max() < 2e-3  # within the config's FERROR: the loop is stable
    assert leftovers() == []
