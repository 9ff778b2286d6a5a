"""Speed of the machine's node set (issue 18): the last printed line is one JSON object.

- lockstep_realtime_factor: `feed-twin run PROGRAM --config config/machine_default.yaml`, the
  three linear axes each with a sim node in its own process and its controller node beside it
  (ros.controller_processes: with_sim), the G-code node with the recorder (four processes),
  1 kHz exchange, in lockstep: simulated time over the wall time of the first
  axis's sim from its first to its last exchange (goal >= 2 on this 2-core machine).
- cpu_us_per_exchange: per process (its log's name) its CPU time after set-up (numba
  compilation and DDS discovery excluded) per exchange, and their sum; comparable on a busy
  machine, where the wall-clock figure is not. Also the load average (1 min) before and after.
- with `--realtime-seconds S` (default 0: skipped), the same machine under `--realtime`:
  lateness p50/p99/max of the first axis's exchanges and its missed steps.
- with `--hosts` (root): the same lockstep run split over two network namespaces joined by a
  veth pair (feed_twin/ros/netns.py), the sims in one and the G-code, controller and recorder
  nodes in the other (ros.controller_processes: shared), so that every exchange crosses the
  link twice; reported beside the one-host run: wall time per exchange (1 / (realtime factor
  x 1 kHz)) on each, and the difference, the cost of the link per exchange (two one-way
  trips); also the link's round trip of one UDP datagram (p50/p99 of 2000, from Python).

- with `--against KEY=VALUE` (repeatable): each lockstep run of the machine file is followed
  by one of a copy with those `ros:` fields (controller_processes=shared: every axis's
  controller in one process; with per_axis and command_batch=false: a process per controller
  and a datagram per setpoint), interleaved `--repeat`
  times; per run the realtime factor, the CPU per exchange of every process and in all, and
  the load average at its start and end. `--before N` is `--against record_batch=N`.

    .venv/bin/python benchmarks/machine_nodes.py [--lockstep-seconds 10] [--realtime-seconds 0]
        [--hosts] [--against controller_processes=shared]
        [--before 0] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

from feed_twin.ros.domain import private_graph_env, reserve_domain_id

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"


def program(seconds: float) -> str:
    """Moves of all three linear axes at once (100 x 60 x 40 mm at 6 m/min), about `seconds`."""
    lines = ["%", "G21 G90 G54 G64", "G1 X0 Y0 Z100 F6000"]
    per_cycle = 2.6  # [s] two moves of 124 mm at 6 m/min with acceleration, two 0.05 s dwells
    for _ in range(max(1, round(seconds / per_cycle))):
        lines += ["G1 X100 Y60 Z140", "G4 P0.05", "G1 X0 Y0 Z100", "G4 P0.05"]
    lines += ["M30", "%", ""]
    return "\n".join(lines)


def machine_with(directory: Path, settings: dict[str, object]) -> Path:
    """The machine file with its ros: fields `settings` replaced (its axis files by absolute
    path)."""
    data = yaml.safe_load(MACHINE.read_text())
    data["ros"].update(settings)
    for entry in data["axes"].values():
        if "include" in entry:
            entry["include"] = str(MACHINE.parent / entry["include"])
    path = directory / f"machine_{'_'.join(f'{k}_{v}' for k, v in settings.items())}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def ros_setting(text: str) -> tuple[str, object]:
    """`KEY=VALUE` of --against: a ros: field of the machine file and its YAML value."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE (a ros: field)")
    return key, yaml.safe_load(value)


def command(directory: Path, name: str, seconds: float, machine: Path = MACHINE) -> list[str]:
    prog = directory / f"{name}.ngc"
    prog.write_text(program(seconds))
    return [
        sys.executable, "-m", "feed_twin.cli", "run", str(prog), "--config", str(machine),
        "--out", str(directory / "bags"), "--name", name, "--json",
    ]  # fmt: skip


def run(
    directory: Path, name: str, seconds: float, realtime: bool, machine: Path = MACHINE
) -> dict:
    args = command(directory, name, seconds, machine) + (["--realtime"] if realtime else [])
    with reserve_domain_id() as domain:
        env = dict(os.environ)
        env.update(private_graph_env(domain.domain_id))
        proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"{name}: feed-twin run failed ({proc.returncode}):\n{proc.stderr}")
    record = with_cpu(directory, name, json.loads(proc.stdout.strip().splitlines()[-1]))
    record["cpu_us_per_exchange_total"] = round(sum(record["cpu_us_per_exchange"].values()), 1)
    return record


def interleaved(directory: Path, seconds: float, settings: dict, repeat: int) -> list:
    """Lockstep runs of the machine file and of it with the ros: fields `settings`,
    alternating; per run the realtime factor, the CPU per exchange of each process and in all,
    and the load average (1 min) at its start and end."""
    other = machine_with(directory, settings)
    label_other = ", ".join(f"{k} {v}" for k, v in settings.items())
    rows = []
    for i in range(repeat):
        for label, machine in (("now", MACHINE), (label_other, other)):
            load = os.getloadavg()[0]
            rec = run(directory, f"ab{i}_{'now' if machine == MACHINE else 'other'}", seconds,
                      False, machine)  # fmt: skip
            rows.append({
                "config": label, "load_start": round(load, 2),
                "load_end": round(os.getloadavg()[0], 2),
                "realtime_factor": round(rec["timing_realtime_factor"], 3),
                "cpu_us_per_exchange": rec["cpu_us_per_exchange"],
                "cpu_us_per_exchange_total": rec["cpu_us_per_exchange_total"],
                "contour_error_max_m": rec["contour_error_max_m"],
            })  # fmt: skip
            print(json.dumps(rows[-1]))
    return rows


def with_cpu(directory: Path, name: str, record: dict) -> dict:
    steps = record["timing_steps"]
    cpu = {}
    for log in sorted((directory / "bags" / f"{name}.logs").glob("*.log")):
        match = re.search(r"^CPU \S+ [\d.]+ s, ([\d.]+) s after set-up", log.read_text(), re.M)
        if match:
            cpu[log.stem] = round(float(match[1]) / steps * 1e6, 1)
    record["cpu_us_per_exchange"] = cpu
    return record


def run_on_two_hosts(directory: Path, seconds: float) -> dict:
    """The lockstep run with the sims behind a veth link from the rest; the NC side's record
    with the sims' timing."""
    from feed_twin.nodeset.auth import KEY_FILE_ENV, new_key, write_key_file
    from feed_twin.ros.netns import linked_namespaces

    # the controllers on the NC's side, away from the sims' processes
    args = command(
        directory, "hosts", seconds, machine_with(directory, {"controller_processes": "shared"})
    )
    with reserve_domain_id() as domain, linked_namespaces("fb", directory) as (axes, nc):
        write_key_file(directory / "run.key", new_key())  # both sides' run key, mode 0600
        base = {**os.environ, KEY_FILE_ENV: str(directory / "run.key")}
        args += ["--domain-id", str(domain.domain_id), "--start"]
        procs = [
            subprocess.Popen(side.command([*args, start]), env=side.env(base),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for side, start in ((axes, "sim"), (nc, "gcode,controller,recorder"))
        ]  # fmt: skip
        outs = [p.communicate(timeout=1800) for p in procs]
        rtt = link_round_trip(axes, nc)
    for p, (_, err) in zip(procs, outs, strict=True):
        if p.returncode != 0:
            raise SystemExit(f"hosts: feed-twin run failed ({p.returncode}):\n{err}")
    sims, rest = (json.loads(out.strip().splitlines()[-1]) for out, _ in outs)
    record = {**rest, **{k: v for k, v in sims.items() if k.startswith("timing_")}}
    record["link_rtt_us"] = rtt
    return with_cpu(directory, "hosts", record)


ECHO = """
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind((sys.argv[1], 47001))
print("ready", flush=True)
while True:
    data, peer = s.recvfrom(64)
    if data == b"end":
        break
    s.sendto(data, peer)
"""
PING = """
import json, socket, sys, time
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t = []
for _ in range(2000):
    start = time.perf_counter()
    s.sendto(b"x", (sys.argv[1], 47001))
    s.recvfrom(64)
    t.append(time.perf_counter() - start)
s.sendto(b"end", (sys.argv[1], 47001))
t.sort()
print(json.dumps({"p50": t[1000] * 1e6, "p99": t[1980] * 1e6}))
"""


def link_round_trip(a, b) -> dict:
    """Round trip of a small UDP datagram a -> b -> a over the link [us], Python both ends."""
    echo = subprocess.Popen(b.command([sys.executable, "-c", ECHO, b.address]),
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert echo.stdout is not None and echo.stdout.readline().strip() == "ready"
    ping = subprocess.run(a.command([sys.executable, "-c", PING, b.address]),
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    echo.wait(timeout=30)
    return {k: round(v, 1) for k, v in json.loads(ping.stdout).items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--lockstep-seconds", type=float, default=10.0)
    parser.add_argument("--realtime-seconds", type=float, default=0.0)
    parser.add_argument("--hosts", action="store_true", help="also split over two namespaces")
    parser.add_argument("--before", type=int, default=None, help="A/B against this record_batch")
    parser.add_argument(
        "--against", type=ros_setting, action="append", metavar="KEY=VALUE",
        help="A/B against the machine file with this ros: field (controller_processes=per_axis;"
        " repeat it for several fields at once)",
    )  # fmt: skip
    parser.add_argument("--repeat", type=int, default=3, help="A/B pairs with --before/--against")
    args = parser.parse_args()
    result: dict[str, object] = {"load_start": os.getloadavg()[0], "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="machine_nodes_") as tmp:
        directory = Path(tmp)
        run(directory, "warm", 0.5, False)  # compiles and caches every axis's kernels
        load = os.getloadavg()[0]
        lock = run(directory, "lockstep", args.lockstep_seconds, False)
        result.update({
            "lockstep_realtime_factor": lock["timing_realtime_factor"],
            "lockstep_steps": lock["timing_steps"],
            "cpu_us_per_exchange": lock["cpu_us_per_exchange"],
            "cpu_us_per_exchange_total": lock["cpu_us_per_exchange_total"],
            "load_before_lockstep": load,
            "load_after_lockstep": os.getloadavg()[0],
            "contour_error_max_m": lock["contour_error_max_m"],
            "following_error_max_m": lock["following_error_max_m"],
        })  # fmt: skip
        print(f"lockstep: {lock['timing_realtime_factor']:.2f}x real time, CPU per exchange "
              f"[us]: {lock['cpu_us_per_exchange']}")  # fmt: skip
        against = dict(args.against or [])
        if args.before is not None:
            against["record_batch"] = args.before
        if against:
            result["interleaved"] = interleaved(
                directory, args.lockstep_seconds, against, args.repeat
            )
        if args.hosts:
            hosts = run_on_two_hosts(directory, args.lockstep_seconds)
            one = 1e3 / lock["timing_realtime_factor"]  # [us] wall per 1 ms exchange
            two = 1e3 / hosts["timing_realtime_factor"]
            result.update({
                "hosts_realtime_factor": hosts["timing_realtime_factor"],
                "hosts_cpu_us_per_exchange": hosts["cpu_us_per_exchange"],
                "wall_us_per_exchange_one_host": round(one, 1),
                "wall_us_per_exchange_two_hosts": round(two, 1),
                "link_cost_us_per_exchange": round(two - one, 1),
                "link_udp_rtt_us": hosts["link_rtt_us"],
            })  # fmt: skip
            print(f"two hosts: {hosts['timing_realtime_factor']:.2f}x real time, "
                  f"{two:.0f} us per exchange against {one:.0f} us on one host")  # fmt: skip
        rt = None
        if args.realtime_seconds > 0:
            try:
                rt = run(directory, "realtime", args.realtime_seconds, True)
            except SystemExit as exc:  # a trip on a loaded machine is a figure too
                result["realtime_error"] = " ".join(str(exc).splitlines()[:2])[:300]
        if rt is not None:
            for key in ("lateness_p50_ms", "lateness_p99_ms", "lateness_max_ms", "missed_steps"):
                result[f"realtime_{key}"] = rt.get(f"timing_{key}")
            result["realtime_steps"] = rt["timing_steps"]
            print(f"realtime: {json.dumps({k: v for k, v in result.items() if 'realtime_' in k})}")
    result["load_end"] = os.getloadavg()[0]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
