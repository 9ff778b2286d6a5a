"""The twin as a LinuxCNC realtime HAL component: the C kernel built with `halcompile`.

    feed-twin hal --config config/axis_default.yaml --out build/ [--servo-period 1e-3] [--install]

writes `feed_twin_axis.comp` (the component header, then the C kernel of feed_twin.native.emit
pasted after it: one self-contained file) and, with --install, runs `halcompile --install`
(root: the module goes to /usr/lib/linuxcnc/modules, the only place `loadrt` takes it from).
In HAL: `loadrt feed_twin_axis`, `addf feed-twin-axis servo-thread`.

halcompile builds with LinuxCNC's realtime flags (-Os, IEEE arithmetic, no -march: `fma` is the
C library's, correctly rounded), so the component computes the doubles the engine computes.

Every call of its function advances the twin by exactly one servo period: the whole number of
base ticks the period spans (16 of 62.5 us for axis_default at 1 ms), the command held. A thread
of another period is refused: the function then never steps, sets `period-error` and writes one
message to LinuxCNC's log (rtapi_print_msg, RTAPI_MSG_ERR).

Pins at the configured boundary (controller mode), in machine units (`units-per-m`, default
1000: millimetres):
- position: `pos-cmd`, `vel-cmd`, `acc-cmd` in (LinuxCNC's joint.N.motor-pos-cmd, vel-cmd,
  acc-cmd; the twin's own drive closes the position loop, as a CSP drive does);
- velocity: `vel-cmd` in (the drive's velocity setpoint, e.g. LinuxCNC's PID output);
- torque: `current-cmd` in [A] (LinuxCNC's PID output as the q-current setpoint);
- out: `pos-fb` (the feedback the drive uses: encoder through the lead, or the linear scale),
  `enc-pos-fb`, `scale-pos-fb`, `vel-fb` (the drive's estimate), `following-error` (the drive's),
  `current-q` [A] (commanded), `fault` (FAULT_* code), `period-error`, `ticks`.
`enable` (in, default on) switches the drive's power stage, as LinuxCNC's joint.N.amp-enable-out
does a real amplifier's (a rising edge also acknowledges a latched fault, as a drive's fault
reset on re-enable): before LinuxCNC is on and homed its position command is not yet the
machine's, and a drive enabled then would latch a following-error fault. `start-pos` (param,
machine units) is the table position the twin starts from, at rest, taken at the first call.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

from feed_twin.control import layout
from feed_twin.core import signals
from feed_twin.native.emit import CKernel, c_kernel

HAL_PACKAGE = "linuxcnc-uspace-dev"
MODULE = "feed_twin_axis"


class HalcompileMissingError(RuntimeError):
    """halcompile is not installed."""


def find_halcompile(name: str = "halcompile") -> str:
    path = shutil.which(name)
    if path is None:
        raise HalcompileMissingError(
            f"no `{name}` on the PATH: install the Debian package {HAL_PACKAGE} "
            f"(apt-get install {HAL_PACKAGE}; tools/setup.sh does as root)"
        )
    return path


_HEAD = """component {module} "feed_twin axis twin of {source}: one servo period of {ticks} \
base ticks ({h_us:g} us) per call";
{pins}
pin out float pos_fb "position feedback the drive uses [machine units]";
pin out float enc_pos_fb "motor encoder through the screw lead [machine units]";
pin out float scale_pos_fb "linear scale [machine units]";
pin out float vel_fb "the drive's velocity estimate [machine units/s]";
pin out float following_error "the drive's following error [machine units]";
pin out float current_q "commanded q current [A]";
pin out s32 fault "FAULT_* code of the drive (0: none, 3: disabled)";
pin out bit period_error "the thread's period is not the servo period this was built for";
pin out s32 ticks "base ticks simulated (wraps)";
pin in bit enable = 1 "power stage on (e.g. joint.N.amp-enable-out); a rising edge clears a \
latched fault";
param rw float units_per_m = 1000.0 "machine units per metre";
param rw float start_pos = 0.0 "table position at the start [machine units]";
function _ fp "advance the twin by one servo period";
option singleton yes;
option extra_setup yes;
license "Apache-2.0";
author "feed_twin";
;;
"""
_PINS = {
    "position": (
        'pin in float pos_cmd "position command [machine units]";\n'
        'pin in float vel_cmd "velocity command (feed-forward) [machine units/s]";\n'
        'pin in float acc_cmd "acceleration command (feed-forward) [machine units/s^2]";'
    ),
    "velocity": 'pin in float vel_cmd "velocity setpoint [machine units/s]";',
    "torque": 'pin in float current_cmd "q-current setpoint [A]";',
}
_REF = {
    "position": (
        f"    ref[{signals.REF_POS_M}] = pos_cmd / units_per_m;\n"
        f"    ref[{signals.REF_VEL_M_S}] = vel_cmd / units_per_m;\n"
        f"    ref[{signals.REF_ACC_M_S2}] = acc_cmd / units_per_m;"
    ),
    "velocity": f"    ref[{signals.REF_VEL_EXT_M_S}] = vel_cmd / units_per_m;",
    "torque": f"    ref[{signals.REF_I_Q_EXT_A}] = current_cmd;",
}
_BODY = """
static ft_model *model;
static int started, refused, was_enabled;
static const double start_map[FT_N_X] = {{{start_map}}}; /* state per metre of table position */

EXTRA_SETUP()
{{
    (void)prefix; (void)extra_arg;
    model = ft_create();
    return model ? 0 : -ENOMEM;
}}

FUNCTION(_)
{{
    double ref[FT_REF_SIZE] = {{0}};
    if (period != {period_ns}L) {{
        if (!refused)
            rtapi_print_msg(RTAPI_MSG_ERR, "{module}: thread period %ld ns, but built for a "
                            "servo period of {period_ns} ns ({ticks} ticks of {h_ns} ns): "
                            "not stepping (rebuild with feed-twin hal --servo-period)\\n",
                            period);
        refused = 1;
        period_error = 1;
        return;
    }}
    if (!started) {{
        double x[FT_N_X];
        for (int i = 0; i < FT_N_X; ++i) x[i] = start_map[i] * (start_pos / units_per_m);
        ft_set_states(model, x);
        started = 1;
    }}
    if (enable && !was_enabled) ft_set_ctrl_state(model, {s_fault}, {fault_none}); /* fault reset */
    ft_set_ctrl_state(model, {s_enable}, enable ? {stage_on} : {stage_off});
    was_enabled = enable;
{ref}
    ft_set_ref(model, ref);
    ft_step(model, {ticks});
    const double *meas = ft_meas(model), *out = ft_out(model), *cp = ft_ctrl_params(model);
    enc_pos_fb = meas[{meas_theta}] * cp[{m_per_rad}] * units_per_m;
    scale_pos_fb = meas[{meas_scale}] * units_per_m;
    pos_fb = (int)cp[{feedback_scale}] == {feedback_scale_code} ? scale_pos_fb : enc_pos_fb;
    vel_fb = out[{out_vel}] * units_per_m;
    following_error = out[{out_fe}] * units_per_m;
    current_q = out[{out_iq}];
    fault = (int)out[{out_fault}];
    ticks = (int)ft_tick(model);
}}
"""


def comp_source(
    axis, servo_period_s: float, *, mode: str | None = None, module: str = MODULE
) -> str:
    """The .comp text of `axis` (feed_twin.sim.config.AxisConfig) for this servo period, at
    the configured boundary or at `mode` (position, velocity, torque), as HAL module `module`
    (its pins and function are named after it: feed_twin_axis -> feed-twin-axis.*)."""
    from feed_twin.control.layout import build_cascade, with_mode

    if not re.fullmatch(r"[a-z][a-z0-9_]*", module):
        raise ValueError(f"module = {module!r}: a HAL module name is [a-z][a-z0-9_]*")
    if axis.controller is None:
        raise ValueError(f"{axis.source}: the HAL component needs a controller section")
    h = axis.engine.base_period_s
    ticks = round(servo_period_s / h)
    if ticks < 1 or abs(ticks * h - servo_period_s) > 1e-9 * servo_period_s:
        raise ValueError(
            f"servo period {servo_period_s!r} s: must be a whole number of base periods "
            f"(engine.base_period_s = {h!r} s of {axis.source})"
        )
    cascade = build_cascade(axis.controller)
    if mode is not None:
        cascade = with_mode(cascade, mode)
    mode = cascade.config.mode
    kernel: CKernel = c_kernel(
        axis.plant,
        base_period_s=h,
        controller=cascade,
        substeps=axis.engine.substeps,
        seed=axis.engine.seed,
    )
    load = axis.plant.coordinates[-1]
    start_map = axis.plant.initial_state({load.name: 1.0})
    head = _HEAD.format(
        module=module, source=axis.source, ticks=ticks, h_us=h * 1e6, pins=_PINS[mode]
    )
    body = _BODY.format(
        start_map=", ".join(repr(float(v)) for v in start_map),
        period_ns=round(servo_period_s * 1e9),
        h_ns=round(h * 1e9),
        ticks=ticks,
        module=module,
        ref=_REF[mode],
        meas_theta=signals.MEAS_THETA_ENC_RAD,
        meas_scale=signals.MEAS_X_SCALE_M,
        m_per_rad=layout.P_M_PER_RAD,
        feedback_scale=layout.P_FEEDBACK_SCALE,
        feedback_scale_code=layout.FEEDBACK_SCALE,
        out_vel=signals.OUT_VEL_EST_M_S,
        out_fe=signals.OUT_FOLLOWING_ERROR_M,
        out_iq=signals.OUT_I_Q_REF_A,
        out_fault=signals.OUT_FAULT,
        s_fault=layout.S_FAULT,
        s_enable=layout.S_ENABLE_CMD,
        fault_none=f"{float(signals.FAULT_NONE)!r}",
        stage_on=f"{float(layout.STAGE_ON)!r}",
        stage_off=f"{float(layout.STAGE_OFF)!r}",
    )
    # halcompile compiles one file: the header's declarations go in front of the kernel
    header = kernel.header.replace("#include <stdint.h>", "#include <stdint.h>\n#include <errno.h>")
    source = kernel.source.replace('#include "feed_twin_axis.h"', header)
    return head + source + body


def write_comp(
    axis, out_dir: Path, servo_period_s: float, *, mode: str | None = None, module: str = MODULE
) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{module}.comp"
    path.write_text(comp_source(axis, servo_period_s, mode=mode, module=module))
    return path


def halcompile(comp: Path, *, install: bool) -> Path:
    """Build (and install) the component; returns the built module's path."""
    tool = find_halcompile()
    mode = "--install" if install else "--compile"
    result = subprocess.run(
        [tool, mode, comp.name], cwd=comp.parent, capture_output=True, text=True
    )
    if result.returncode != 0:
        raise RuntimeError(f"{comp}: halcompile {mode} failed:\n{result.stderr[-3000:]}")
    return comp.with_suffix(".so")
