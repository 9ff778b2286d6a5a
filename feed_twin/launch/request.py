"""What `feed-twin run` was asked for, typed: the config, the program, the mode and its options.

`RunRequest.from_args` reads `feed-twin run`'s options once; the planner (machine.py)
and the report's mode name (`mode_name`) read the request, not the argument namespace.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

Nc = Literal["feed_twin", "linuxcnc"]
# how the nodes run: each process its own (`nodes`), every node in this process on one
# executor (`single_process`), or no nodes at all: the engines in this process (`in_process`)
Transport = Literal["nodes", "single_process", "in_process"]
NCS: tuple[Nc, ...] = ("feed_twin", "linuxcnc")


@dataclass(frozen=True, kw_only=True)
class RunRequest:
    """One run's config, program and options."""

    config: Path
    program: Path | None  # None: the command stream comes from outside (--no-gcode)
    shadow: bool = False  # the stand-in machine (or LinuxCNC) with the shadow twin beside it
    nc: Nc = "feed_twin"
    transport: Transport = "nodes"
    realtime: bool = False  # paced by the wall clock
    no_gcode: bool = False
    optional_stop: bool = False  # M1 pauses
    max_time_s: float | None = None  # [s] simulated at most
    live_url: str | None = None  # the live viewer's gRPC address, when one runs
    startup_timeout_s: float = 120.0  # [s] for every node to come up and see its peers
    input_timeout_s: float = 10.0  # [s] of silence on an input topic
    axes: tuple[str, ...] | None = None  # machine config: the simulated axes (None: all)
    settle_s: float = 0.2  # [s] machine config: simulated after the program's end
    start: str | None = None  # machine config: the processes started here (--start)

    def __post_init__(self) -> None:
        if self.nc not in NCS:
            raise ValueError(f"nc = {self.nc!r}: must be one of {', '.join(NCS)}")
        if self.startup_timeout_s <= 0:
            raise ValueError(f"startup_timeout_s = {self.startup_timeout_s!r}: must be > 0")
        if self.input_timeout_s <= 0:
            raise ValueError(f"input_timeout_s = {self.input_timeout_s!r}: must be > 0")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> RunRequest:
        """From `feed-twin run`'s parsed options (feed_twin/ros/run_cli.py configure)."""
        transport: Transport = "nodes"
        if getattr(args, "in_process", False):
            transport = "in_process"
        elif getattr(args, "single_process", False):
            transport = "single_process"
        axes = getattr(args, "axes", None)
        return cls(
            config=args.config,
            program=args.program,
            shadow=bool(getattr(args, "shadow", False)),
            nc=getattr(args, "nc", "feed_twin"),
            transport=transport,
            realtime=bool(getattr(args, "realtime", False)),
            no_gcode=bool(getattr(args, "no_gcode", False)),
            optional_stop=bool(getattr(args, "optional_stop", False)),
            max_time_s=getattr(args, "max_time", None),
            live_url=getattr(args, "live_url", None),
            startup_timeout_s=getattr(args, "startup_timeout", 120.0),
            input_timeout_s=getattr(args, "input_timeout", 10.0),
            axes=tuple(axes.split(",")) if axes else None,
            settle_s=getattr(args, "settle", 0.2),
            start=getattr(args, "start", None),
        )

    def common_argv(self) -> list[str]:
        """The timeouts every node of the run takes."""
        return [
            "--startup-timeout", str(self.startup_timeout_s),
            "--input-timeout", str(self.input_timeout_s),
        ]  # fmt: skip
