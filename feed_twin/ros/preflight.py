"""What `feed-twin run` checks before any node starts, and how it treats its outputs.

- The whole config: every section the nodes will load (plant with its plausibility ranges,
  engine, controller, the controller node's own loop set-up, ros, nc, shadow), and whether the
  drive reaches the NC's rapid and feed rates (feed_twin/nodeset/reach.py). A bad config ends the
  run in a second with one line, instead of in the nodes 8-11 s later.
- The output directory: it can be created and written, and its file system has room for the
  bag the program will make (`estimate_bag_bytes`, from the program's planned duration) and the
  dashboard, with a margin.
- Outputs: a file counts as an output only when it is complete (`complete_rrd`: Rerun writes
  its footer when the recording is closed; a killed writer leaves none).

This module does not import rclpy.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from feed_twin.core.config import ConfigError

# Bytes per exchange in the bag: AxisCommand, DriveCommand, AxisFeedback and AxisState with
# their MCAP records, zstd-compressed: sample.ngc at 1 kHz made 2.49 MB in 7331 exchanges
# (340 bytes each); 500 leaves a margin for less compressible runs.
BAG_BYTES_PER_EXCHANGE = 500
# The .rrd dashboard is about as large as the bag (2.42 MB for the same run); and some room.
RRD_FRACTION = 1.0
SPARE_BYTES = 4 * 1024 * 1024
FULL_BYTES = 1024 * 1024  # free space below which a failed run's --out counts as full


def check_run_config(config: Path, *, shadow: bool):
    """Load every section the nodes need; raises ConfigError (one line) for the first problem.

    Returns (ros, nc): the node-set config and the NC config."""
    from feed_twin.gcode import load_nc_config
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.nodeset.controller_core import ControllerCore
    from feed_twin.nodeset.reach import check_reachable
    from feed_twin.sim.config import load_axis_config

    ros = load_node_set_config(config)
    nc = load_nc_config(config)
    if nc.interpolation_period_s < ros.exchange_period_s - 1e-12:
        raise ConfigError(
            f"{config}: nc.interpolation_period_s = {nc.interpolation_period_s!r}: must not "
            f"be shorter than ros.exchange_period_s = {ros.exchange_period_s!r}"
        )
    axis = load_axis_config(config)
    if axis.controller is None:
        raise ConfigError(f"{config}: the node set needs a controller section")
    try:
        ControllerCore(
            axis.controller,
            boundary=ros.boundary,
            exchange_period_s=ros.exchange_period_s,
            gains=ros.node_gains,
        )
    except ValueError as exc:
        raise ConfigError(f"{config}: controller (for the controller node): {exc}") from None
    speed = ros.protection.speed_limit_m_s if ros.protection.enabled else None
    check_reachable(axis, nc, speed, source=str(config))
    if shadow:
        from feed_twin.shadow.config import load_shadow_config

        load_shadow_config(config)
    return ros, nc


# What a run named N writes into --out (single-axis and machine runs, every mode).
RUN_OUTPUT_SUFFIXES = ("", ".rrd", ".logs", "_map.yaml")
MAX_NAME_CHARS = 200  # and a suffix: within a file system's 255-byte names


def run_outputs_of(out: Path, name: str) -> list[Path]:
    """The outputs of a run named `name` that already exist in `out`."""
    paths = [out / f"{name}{suffix}" for suffix in RUN_OUTPUT_SUFFIXES]
    return [path for path in paths if path.exists() or path.is_symlink()]


def run_name(out: Path, name: str | None, stem: str, stamp: str) -> str:
    """The run's name: `name` (--name), which must be a file name and must not be used in `out`
    yet (nothing a run wrote is overwritten); or, without one, `<stem>_<stamp>`, with `_2`,
    `_3`, ... when a run of the same second is there. Raises ConfigError (one line)."""
    if name is None:
        chosen, k = f"{stem}_{stamp}", 1
        while run_outputs_of(out, chosen):
            k += 1
            chosen = f"{stem}_{stamp}_{k}"
        return chosen
    shown = name if len(name) <= 40 else f"{name[:40]}..."
    if not name or name in (".", "..") or "/" in name or "\0" in name:
        raise ConfigError(
            f"--name {shown!r}: must be a file name inside --out, not a path (no '/', not "
            "'.' or '..')"
        )
    if len(name.encode()) > MAX_NAME_CHARS:
        raise ConfigError(f"--name {shown!r}: longer than {MAX_NAME_CHARS} bytes")
    used = run_outputs_of(out, name)
    if used:
        raise ConfigError(
            f"--name {name}: already used in {out} ({', '.join(p.name for p in used)}); choose "
            "another name or --out, nothing was started"
        )
    return name


def estimate_bag_bytes(duration_s: float, exchange_period_s: float) -> int:
    """Bytes the run's bag will take for `duration_s` of simulated time."""
    return int(duration_s / exchange_period_s * BAG_BYTES_PER_EXCHANGE)


def program_duration_s(program: Path, nc) -> float:
    """The planned program's duration [s] (its last sample's time)."""
    from feed_twin.gcode.planner import plan_program_stream

    t_end = 0.0
    for chunk in plan_program_stream(program, nc):
        if len(chunk):
            t_end = float(chunk.t_s[-1])
    return t_end


def check_output_dir(out: Path, need_bytes: int) -> None:
    """The directory exists (or is created), is writable and has room for `need_bytes`."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ConfigError(f"--out {out}: exists and is not a directory") from None
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create it ({exc.strerror})") from None
    probe = out / f".feed_twin_write_test_{os.getpid()}"
    try:
        with open(probe, "wb") as handle:
            handle.write(b"x")
    except OSError as exc:
        raise ConfigError(f"--out {out}: not writable ({exc.strerror})") from None
    finally:
        probe.unlink(missing_ok=True)
    free = shutil.disk_usage(out).free
    need = int(need_bytes * (1.0 + RRD_FRACTION)) + SPARE_BYTES
    if free < need:
        raise ConfigError(
            f"--out {out}: {free / 1e6:.1f} MB free, the run needs about {need / 1e6:.1f} MB "
            f"(bag {need_bytes / 1e6:.1f} MB, dashboard and spare); free some space or choose "
            "another --out"
        )


# A Rerun .rrd that its writer closed ends with the footer's marker: "RRF2FOOT" and a 4-byte
# version (rerun-sdk 0.41; `rerun rrd verify` reports "Missing RRD footer" without it).
RRD_FOOTER_MARKER = b"RRF2FOOT"


def complete_rrd(path: Path) -> bool:
    """The .rrd exists and was closed by its writer; a writer killed mid-run, or one that ran
    out of disk, leaves a file without the footer."""
    try:
        with open(path, "rb") as handle:
            if handle.read(4) != b"RRF2":
                return False
            handle.seek(-12, os.SEEK_END)
            tail = handle.read(12)
    except OSError:
        return False
    return tail[:8] == RRD_FOOTER_MARKER


def estimate_run_bytes(args, ros, nc) -> int:
    """The bag a `feed-twin run` will write: its planned program's length (or --max-time)."""
    duration = 0.0
    if args.program is not None:
        duration = program_duration_s(args.program, nc) + ros.settle_s
    if args.max_time is not None:
        duration = min(duration, args.max_time) if duration else args.max_time
    return estimate_bag_bytes(duration, ros.exchange_period_s)


def run_environment(args, environ):
    """Put the run into its own ROS domain (feed_twin.ros.domain.run_domain) and give its
    nodes the run key (feed_twin.nodeset.auth): a sealed memfd whose number goes into
    `environ` (KEY_FD_ENV; feed_twin.ros.launch passes the descriptor to the node processes,
    nothing else carries the key); returns the domain reservation to hold for the run's life
    (None: the user named the domain)."""
    from feed_twin.nodeset.auth import KEY_FD_ENV, KEY_FILE_ENV, key_memfd, new_key
    from feed_twin.nodeset.guard import OPEN_NC_ENV
    from feed_twin.ros.domain import run_domain

    reservation, domain_id = run_domain(args.domain_id)
    environ["ROS_DOMAIN_ID"] = str(domain_id)
    # a run spread over several computers (`--start`) shares the key file the user made
    # (0600, KEY_FILE_ENV) on each; every other run draws its own key
    if not environ.get(KEY_FILE_ENV):
        environ[KEY_FD_ENV] = str(key_memfd(new_key()))
    environ[OPEN_NC_ENV] = "1" if args.no_gcode else "0"
    return reservation


def end_environment(environ) -> None:
    """The run is over: its key's descriptor is closed and its number leaves `environ`."""
    import contextlib

    from feed_twin.nodeset.auth import KEY_FD_ENV

    text = environ.pop(KEY_FD_ENV, "")
    if text.isdigit():
        with contextlib.suppress(OSError):  # a single-process run's node closed it already
            os.close(int(text))


def shown_output(path: Path, *, rrd: bool = False) -> str | None:
    """The output's path when it is there and complete, else None (never reported)."""
    if rrd:
        return str(path) if complete_rrd(path) else None
    return str(path) if path.exists() else None


def remove_incomplete_rrd(path: Path) -> None:
    """An .rrd without its footer (a killed writer, a full disk) is not kept as an output."""
    if path.exists() and not complete_rrd(path):
        path.unlink(missing_ok=True)


def exit_status(code: int) -> int:
    """The process exit status for a run's code: a node killed by signal N (code -N) is
    128 + N, as a shell reports it, so that `--json`'s exit_code equals the process's."""
    return 128 - code if code < 0 else code


def with_disk_full(reason: str, bag: Path) -> str:
    """A run's end `reason` with the full file system of the bag said first."""
    if reason and shutil.disk_usage(bag.parent).free < FULL_BYTES:
        # The nodes' logs live there too, so a node's own words may be lost: say it here.
        free = shutil.disk_usage(bag.parent).free
        reason = f"the file system of --out is full ({free // 1024} kB free); {reason}"
    return reason


def dashboard_room(bag: Path, rrd: Path) -> str:
    """'' when the output directory has room for the run's .rrd `rrd` (about the bag's size),
    else why not: Rerun's file sink does not raise on a full disk, it blocks its flush."""
    bag_bytes = sum(p.stat().st_size for p in bag.glob("*") if p.is_file())
    need = int(bag_bytes * 1.2) + SPARE_BYTES // 4
    free = shutil.disk_usage(bag.parent).free
    if free < need:
        return (
            f"no room for the dashboard {rrd} ({free / 1e6:.1f} MB free, about "
            f"{need / 1e6:.1f} MB needed); the bag has the whole recording"
        )
    return ""
