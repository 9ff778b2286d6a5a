"""The LinuxCNC machine of an axis config: INI, HAL and parameter files from its `nc:` section.

A 3-axis mill (joints 0, 1, 2 = X, Y, Z, trivial kinematics) whose limits come from
`NcConfig`: per axis `MAX_VELOCITY` = `rapid_m_s` (LinuxCNC 2.9 has one velocity limit per axis,
used for rapids and as the ceiling of feeds), `MAX_ACCELERATION` = `a_max_m_s2`, the soft limits
= the travel, `HOME` = `HOME_OFFSET` = the start position with `HOME_SEARCH_VEL = 0` (homing
without motion); the work offsets G54-G59 go into the interpreter's parameter file; the path
tolerance is set as `G64 P.. Q..` by the runner before the program (LinuxCNC's start-up code does
not bound the blends of a program run in AUTO). The units of the files are millimetres, as
LinuxCNC's; `feed_twin.linuxcnc.samples` converts the recorded pins back to SI.

Each joint has a simulated servo in HAL so that LinuxCNC reports a real following error:

    pid.L (P = Kv, FF1 velocity feed-forward) --velocity--> drive.L (lowpass: the drive's
    velocity loop) --> motor.L (integ) --> scale.L (sum2, offset = home) --> joint.N.motor-pos-fb

With `twin_joint` set, that joint's plant is replaced by the twin: its PID output leaves through
the sampler and the twin's encoder comes back through a HAL `streamer` (virtual commissioning).
The servo thread also carries `feedtwin_clock` (the CLOCK_MONOTONIC time of each period, for the
bridge latency) and the `sampler` that records every period (`feed_twin.linuxcnc.samples`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from feed_twin.core.validate import require_nonnegative, require_positive, require_range
from feed_twin.gcode.config import WORK_OFFSET_CODES, NcConfig
from feed_twin.linuxcnc.samples import sample_layout

MM_PER_M = 1000.0
JOINT_AXES = ("X", "Y", "Z")
INI_NAME = "machine.ini"
HAL_NAME = "machine.hal"
VAR_NAME = "machine.var"
TOOL_TABLE_NAME = "tool.tbl"
# rs274ngc: work offset n (G54 = 1) of axis a (X = 0) is parameter 5201 + 20 n + a.
_WORK_OFFSET_PARAM_BASE = 5201
_WORK_OFFSET_PARAM_STRIDE = 20


@dataclass(frozen=True, kw_only=True)
class HalServo:
    """The simulated servo of each joint in HAL (PID in velocity mode, drive lag, integrator)."""

    servo_period_s: float  # [s] LinuxCNC's servo thread period (SERVO_PERIOD)
    Kv_1_s: float  # [1/s] proportional position gain of pid.L ((mm/s)/mm)
    velocity_ff: float  # [-] FF1: share of the commanded velocity fed forward
    drive_lag_s: float  # [s] time constant of the drive's closed velocity loop (lowpass)
    ferror_m: float  # [m] FERROR: following error that stops the machine at full speed
    min_ferror_m: float  # [m] MIN_FERROR: the same limit at standstill
    sample_depth: int  # [periods] depth of the sampler FIFO (the reader's slack)

    def __post_init__(self) -> None:
        require_range("servo_period_s", self.servo_period_s, 1e-4, 1e-2)
        require_positive("Kv_1_s", self.Kv_1_s)
        require_range("velocity_ff", self.velocity_ff, 0.0, 1.5)
        require_nonnegative("drive_lag_s", self.drive_lag_s)
        require_positive("ferror_m", self.ferror_m)
        require_positive("min_ferror_m", self.min_ferror_m)
        if self.min_ferror_m > self.ferror_m:
            raise ValueError(
                f"min_ferror_m = {self.min_ferror_m!r}: must be <= ferror_m = {self.ferror_m!r}"
            )
        if isinstance(self.sample_depth, bool) or not isinstance(self.sample_depth, int):
            raise ValueError(f"sample_depth = {self.sample_depth!r}: must be an int")
        if not 1000 <= self.sample_depth <= 1_000_000:
            raise ValueError(f"sample_depth = {self.sample_depth!r}: must lie in [1000, 1000000]")

    @property
    def servo_period_ns(self) -> int:
        return round(self.servo_period_s * 1e9)

    @property
    def lowpass_gain(self) -> float:
        """lowpass.gain of a first-order lag with time constant drive_lag_s, sampled exactly."""
        if self.drive_lag_s == 0.0:
            return 1.0
        return 1.0 - math.exp(-self.servo_period_s / self.drive_lag_s)


def servo_for_axis(controller: object | None, *, servo_period_s: float = 1e-3) -> HalServo:
    """The HAL servo of the project's machine: Kv and the following-error limit of the axis
    config's position controller (30 1/s, 2 mm in axis_default), a 2 ms drive velocity loop.

    `controller` is the axis config's `ControllerConfig` (or None: Kv 30 1/s, 2 mm)."""
    position = getattr(controller, "position", None)
    Kv = float(getattr(position, "Kv_1_s", 30.0))
    fe_limit = float(getattr(position, "following_error_limit_m", 2.0e-3))
    return HalServo(
        servo_period_s=servo_period_s,
        Kv_1_s=Kv,
        velocity_ff=1.0,
        # a velocity-controlled servo drive closes its speed loop at a few hundred Hz
        drive_lag_s=2.0e-3,
        ferror_m=fe_limit,
        min_ferror_m=fe_limit / 2.0,
        # 120 s of slack: the reader can stall for that long before a sample is lost
        sample_depth=120_000,
    )


def _axes_xyz(nc: NcConfig) -> tuple:
    if nc.axis_names != JOINT_AXES:
        raise ValueError(
            f"nc.axes = {list(nc.axis_names)!r}: the LinuxCNC machine is a 3-axis mill and needs "
            "exactly the axes X, Y, Z in that order"
        )
    return nc.axes


def _mm(x_m: float) -> str:
    return f"{x_m * MM_PER_M:.6f}".rstrip("0").rstrip(".")


def render_ini(nc: NcConfig, servo: HalServo) -> str:
    """The INI file of the machine (millimetre units, LinuxCNC's own)."""
    axes = _axes_xyz(nc)
    v_max = max(a.rapid_m_s for a in axes)
    a_max = max(a.a_max_m_s2 for a in axes)
    lines = [
        "# Generated by feed_twin.linuxcnc.machine from the nc: section of an axis config.",
        "# Millimetres, as LinuxCNC's; regenerate instead of editing.",
        "[EMC]",
        "VERSION = 1.1",
        "MACHINE = feed_twin-mill",
        "DEBUG = 0",
        "",
        "[DISPLAY]",
        "# the runner's headless program (feed_twin/linuxcnc/_display.py) replaces this line",
        "DISPLAY = dummy",
        "",
        "[TASK]",
        "TASK = milltask",
        "CYCLE_TIME = 0.001",
        "",
        "[RS274NGC]",
        f"PARAMETER_FILE = {VAR_NAME}",
        "RS274NGC_STARTUP_CODE = G21 G17 G90 G94 G40 G49 G80 G54",
        "",
        "[EMCMOT]",
        "EMCMOT = motmod",
        "COMM_TIMEOUT = 1.0",
        f"SERVO_PERIOD = {servo.servo_period_ns}",
        "",
        "[EMCIO]",
        "EMCIO = io",
        "CYCLE_TIME = 0.100",
        f"TOOL_TABLE = {TOOL_TABLE_NAME}",
        "",
        "[HAL]",
        f"HALFILE = {HAL_NAME}",
        "",
        "[TRAJ]",
        "COORDINATES = X Y Z",
        "LINEAR_UNITS = mm",
        "ANGULAR_UNITS = degree",
        f"DEFAULT_LINEAR_VELOCITY = {_mm(v_max)}",
        f"MAX_LINEAR_VELOCITY = {_mm(v_max)}",
        f"DEFAULT_LINEAR_ACCELERATION = {_mm(a_max)}",
        f"MAX_LINEAR_ACCELERATION = {_mm(a_max)}",
        "NO_FORCE_HOMING = 0",
        "",
        "[KINS]",
        "KINEMATICS = trivkins coordinates=XYZ",
        f"JOINTS = {len(axes)}",
    ]
    for axis in axes:
        lines += [
            "",
            f"[AXIS_{axis.name}]",
            f"MAX_VELOCITY = {_mm(axis.rapid_m_s)}",
            f"MAX_ACCELERATION = {_mm(axis.a_max_m_s2)}",
            f"MIN_LIMIT = {_mm(axis.travel_min_m)}",
            f"MAX_LIMIT = {_mm(axis.travel_max_m)}",
        ]
    for joint, (axis, home_m) in enumerate(zip(axes, nc.start_position_m, strict=True)):
        lines += [
            "",
            f"[JOINT_{joint}]",
            "TYPE = LINEAR",
            f"HOME = {_mm(home_m)}",
            f"HOME_OFFSET = {_mm(home_m)}",
            "HOME_SEARCH_VEL = 0",
            "HOME_LATCH_VEL = 0",
            "HOME_SEQUENCE = 0",
            f"MAX_VELOCITY = {_mm(axis.rapid_m_s)}",
            f"MAX_ACCELERATION = {_mm(axis.a_max_m_s2)}",
            f"MIN_LIMIT = {_mm(axis.travel_min_m)}",
            f"MAX_LIMIT = {_mm(axis.travel_max_m)}",
            f"FERROR = {_mm(servo.ferror_m)}",
            f"MIN_FERROR = {_mm(servo.min_ferror_m)}",
            f"P = {servo.Kv_1_s!r}",
            f"FF1 = {servo.velocity_ff!r}",
            # the PID may ask for twice the rapid speed while it catches up a following error
            f"MAX_OUTPUT = {_mm(2.0 * axis.rapid_m_s)}",
        ]
    return "\n".join(lines) + "\n"


def render_hal(nc: NcConfig, servo: HalServo, *, twin_joint: int | None = None) -> str:
    """The HAL file: motion, a servo per joint, the clock and the sampler in the servo thread."""
    axes = _axes_xyz(nc)
    layout = sample_layout()
    names = [a.name.lower() for a in axes]
    plant = [n for j, n in enumerate(names) if j != twin_joint]
    lines = [
        "# Generated by feed_twin.linuxcnc.machine; regenerate instead of editing.",
        "loadrt [KINS]KINEMATICS",
        "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS",
        "loadrt feedtwin_clock",
        f"loadrt pid names={','.join('pid.' + n for n in names)}",
    ]
    if plant:
        lines += [
            f"loadrt lowpass names={','.join('drive.' + n for n in plant)}",
            f"loadrt integ names={','.join('motor.' + n for n in plant)}",
            f"loadrt sum2 names={','.join('scale.' + n for n in plant)}",
        ]
    if twin_joint is not None:
        lines.append(f"loadrt streamer depth={servo.sample_depth} cfg=f")
    lines += [
        f"loadrt sampler depth={servo.sample_depth} cfg={layout.hal_cfg}",
        "",
        "addf feedtwin-clock.0 servo-thread",
    ]
    if twin_joint is not None:
        # before motion: the feedback the twin latched at the start of the previous period,
        # a fieldbus drive's one-cycle delay
        lines.append("addf streamer.0 servo-thread")
    lines += [
        "addf motion-command-handler servo-thread",
        "addf motion-controller servo-thread",
    ]
    for j, n in enumerate(names):
        lines.append(f"addf pid.{n}.do-pid-calcs servo-thread")
        if j != twin_joint:
            lines += [
                f"addf drive.{n} servo-thread",
                f"addf motor.{n} servo-thread",
                f"addf scale.{n} servo-thread",
            ]
    lines += ["addf sampler.0 servo-thread", ""]
    for j, (n, home_m) in enumerate(zip(names, nc.start_position_m, strict=True)):
        lines += [
            f"setp pid.{n}.Pgain [JOINT_{j}]P",
            f"setp pid.{n}.Igain 0",
            f"setp pid.{n}.Dgain 0",
            f"setp pid.{n}.FF1 [JOINT_{j}]FF1",
            f"setp pid.{n}.maxoutput [JOINT_{j}]MAX_OUTPUT",
            f"net {n}-pos-cmd joint.{j}.motor-pos-cmd => pid.{n}.command",
            f"net {n}-vel-cmd joint.{j}.vel-cmd => pid.{n}.command-deriv",
            f"net {n}-enable joint.{j}.amp-enable-out => pid.{n}.enable",
            f"net {n}-joint-pos-cmd joint.{j}.pos-cmd",
            f"net {n}-joint-pos-fb joint.{j}.pos-fb",
            f"net {n}-acc-cmd joint.{j}.acc-cmd",
            f"net {n}-f-error joint.{j}.f-error",
            f"net {n}-output pid.{n}.output",
        ]
        if j == twin_joint:
            lines.append(
                f"net {n}-pos-fb streamer.0.pin.0 => pid.{n}.feedback joint.{j}.motor-pos-fb"
            )
        else:
            lines += [
                f"setp drive.{n}.gain {servo.lowpass_gain!r}",
                f"setp scale.{n}.offset {_mm(home_m)}",
                f"net {n}-output => drive.{n}.in",
                f"net {n}-vel drive.{n}.out => motor.{n}.in",
                f"net {n}-pos motor.{n}.out => scale.{n}.in0",
                f"net {n}-pos-fb scale.{n}.out => pid.{n}.feedback joint.{j}.motor-pos-fb",
            ]
        lines.append("")
    lines += [
        "net program-line motion.program-line",
        "net tick feedtwin-clock.0.tick",
        "net tick-time feedtwin-clock.0.time-s",
    ]
    for index, column in enumerate(layout.columns):
        lines.append(f"net {column.signal} => sampler.0.pin.{index}")
    lines += [
        "",
        "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in",
        "net tool-prepare iocontrol.0.tool-prepare => iocontrol.0.tool-prepared",
        "net tool-change iocontrol.0.tool-change => iocontrol.0.tool-changed",
    ]
    return "\n".join(lines) + "\n"


def render_var(nc: NcConfig) -> str:
    """The interpreter's parameter file: G54 active, the work offsets G54-G59 in millimetres."""
    _axes_xyz(nc)
    rows = [(5220, 1.0)]
    for n, code in enumerate(WORK_OFFSET_CODES, start=1):
        origin = getattr(nc.work_offsets_m, code)
        base = _WORK_OFFSET_PARAM_BASE + _WORK_OFFSET_PARAM_STRIDE * n
        rows += [(base + a, origin[a] * MM_PER_M) for a in range(len(JOINT_AXES))]
    return "".join(f"{number}\t{value:.6f}\n" for number, value in sorted(rows))


def machine_files(
    nc: NcConfig, servo: HalServo, *, twin_joint: int | None = None
) -> dict[str, str]:
    """File name -> text of the whole machine directory."""
    return {
        INI_NAME: render_ini(nc, servo),
        HAL_NAME: render_hal(nc, servo, twin_joint=twin_joint),
        VAR_NAME: render_var(nc),
        TOOL_TABLE_NAME: "T1 P1 D0 Z0 ;no tool\n",
    }


def write_machine(
    directory: str | Path, nc: NcConfig, servo: HalServo, *, twin_joint: int | None = None
) -> Path:
    """Write the machine files into `directory` (created); returns the INI's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for name, text in machine_files(nc, servo, twin_joint=twin_joint).items():
        (directory / name).write_text(text, encoding="utf-8")
    return directory / INI_NAME


def check_machine(directory: str | Path, nc: NcConfig, servo: HalServo) -> list[str]:
    """Names of the files in `directory` that differ from what `nc` and `servo` generate."""
    directory = Path(directory)
    stale = []
    for name, text in machine_files(nc, servo).items():
        path = directory / name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            stale.append(str(path))
    return stale


def machine_for_config(config_path: str | Path) -> tuple[NcConfig, HalServo]:
    """The NC and HAL servo of an axis config file (its `nc:` and `controller:` sections)."""
    from feed_twin.gcode.config import load_nc_config
    from feed_twin.sim.config import load_axis_config

    nc = load_nc_config(config_path)
    servo = servo_for_axis(load_axis_config(config_path).controller)
    return nc, servo


def main(argv: list[str] | None = None) -> int:
    """`python -m feed_twin.linuxcnc.machine CONFIG DIR [--check]`: write (or check) DIR."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m feed_twin.linuxcnc.machine")
    parser.add_argument("config", help="axis config YAML (nc: and controller: sections)")
    parser.add_argument("directory", help="machine directory, e.g. config/linuxcnc")
    parser.add_argument("--check", action="store_true", help="only compare, exit 1 if stale")
    args = parser.parse_args(argv)
    nc, servo = machine_for_config(args.config)
    if args.check:
        stale = check_machine(args.directory, nc, servo)
        for path in stale:
            print(f"{path}: differs from what {args.config} generates")
        return 1 if stale else 0
    print(write_machine(args.directory, nc, servo))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
