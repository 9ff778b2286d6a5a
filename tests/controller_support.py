"""The loops of a test's controller config, for tests whose fixture is known to have them.

`ControllerConfig`'s loops are optional (a velocity-mode drive has no position loop, a node's
controller no current loop); these name the loop the test relies on, and fail with the config's
shape when the fixture lacks it, not with an AttributeError on None.
"""

from __future__ import annotations

from feed_twin.control.config import (
    ControllerConfig,
    CurrentLoopConfig,
    PositionLoopConfig,
    VelocityLoopConfig,
)


def _shape(config: ControllerConfig) -> str:
    present = [n for n in ("position", "velocity", "current") if getattr(config, n) is not None]
    return f"mode {config.mode!r}, loops {present}"


def position_loop(config: ControllerConfig) -> PositionLoopConfig:
    assert config.position is not None, f"the test needs a position loop: {_shape(config)}"
    return config.position


def velocity_loop(config: ControllerConfig) -> VelocityLoopConfig:
    assert config.velocity is not None, f"the test needs a velocity loop: {_shape(config)}"
    return config.velocity


def current_loop(config: ControllerConfig) -> CurrentLoopConfig:
    assert config.current is not None, f"the test needs a current loop: {_shape(config)}"
    return config.current
