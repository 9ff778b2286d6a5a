"""LinuxCNC as the machine of a machine config's shadow twin: its NC, HAL servo and joints.

LinuxCNC runs the project's 3-axis mill (feed_twin.linuxcnc.machine: joints 0, 1, 2 = X, Y, Z,
trivial kinematics, a simulated servo loop per joint); the machine config's NC becomes its INI
(limits, start position, work offsets) and the simulated axes' twins shadow their joints. So
the NC must have exactly the axes X, Y, Z (a rotary or U/V/W axis has no joint there), and the
simulated axes must share one position loop (one HAL servo description serves every joint):
otherwise a one-line ConfigError naming the machine file and the axis.
"""

from __future__ import annotations

from feed_twin.core.config import ConfigError
from feed_twin.gcode.config import NcConfig
from feed_twin.linuxcnc.machine import JOINT_AXES, HalServo, servo_for_axis
from feed_twin.machine.config import MachineConfig


def linuxcnc_machine(machine: MachineConfig) -> tuple[NcConfig, HalServo]:
    """The NC and HAL servo LinuxCNC runs for `machine` (module docstring)."""
    source = machine.source
    for name in machine.nc.axis_names:
        if name not in JOINT_AXES:
            raise ConfigError(
                f"{source}: nc: axis {name}: the LinuxCNC machine (a 3-axis mill, joints "
                f"{', '.join(JOINT_AXES)}) has no {name}; shadow it on a machine config without it"
            )
    missing = [a for a in JOINT_AXES if a not in machine.nc.axis_names]
    if missing or machine.nc.axis_names != JOINT_AXES:
        raise ConfigError(
            f"{source}: nc.axes = {list(machine.nc.axis_names)!r}: the LinuxCNC machine needs "
            f"the axes {', '.join(JOINT_AXES)} in that order"
        )
    servos = {a: servo_for_axis(config.controller) for a, config in machine.axes.items()}
    first = next(iter(servos))
    for axis, servo in servos.items():
        if servo != servos[first]:
            raise ConfigError(
                f"{source}: axes {first} and {axis}: their position loops differ (Kv "
                f"{servos[first].Kv_1_s!r} and {servo.Kv_1_s!r} 1/s, following-error limit "
                f"{servos[first].ferror_m!r} and {servo.ferror_m!r} m): the LinuxCNC machine "
                "has one HAL servo for every joint"
            )
    return machine.nc, servos[first]


def machine_joints(machine: MachineConfig) -> dict[str, int]:
    """Simulated NC axis -> its LinuxCNC joint."""
    return {axis: JOINT_AXES.index(axis) for axis in machine.axes}
