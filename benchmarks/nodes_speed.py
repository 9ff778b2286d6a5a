"""Speed of the ROS 2 node set (issue 5 targets): the last printed line is one JSON object.

- lockstep_realtime_factor: `feed-twin run` in lockstep, the G-code, controller and sim nodes
  in separate processes (plus the recorder), 1 kHz exchange, a 10 s program: simulated time
  over the wall time from the first to the last exchange (target >= 4).
- realtime_p99_lateness_ms, realtime_lateness_p50/max_ms, missed_steps: `--realtime`, 1 kHz,
  a 60 s program (target p99 <= 0.5 ms, 0 missed steps).
Also reported: the machine's load average at the start and the end, since the figures depend
on it, and per node process its CPU seconds after set-up (numba compilation and DDS discovery
excluded) and those per exchange, which stay comparable on a busy machine where the wall-clock
figures do not. And what the platform itself allows (`probe_*`, `--probe-seconds`, 0 to
skip): a process with nothing to do but wake up every 1 ms, under the sim node's real-time
settings (SCHED_FIFO 50, PM QoS wake-up latency 0), counts the wake-ups that came more than
1 ms late, i.e. the steps that no node could have made. On this virtual machine such stalls
come about every few seconds, on a 100 ms grid, with no other process running: the vCPU does
not run (the guest sees the sleeping task "running" for the whole stall).

    .venv/bin/python benchmarks/nodes_speed.py [--realtime-seconds 60] [--lockstep-seconds 10]
        [--probe-seconds 30] [--config config/axis_default.yaml]
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

from feed_twin.ros.domain import private_graph_env, reserve_domain_id

ROOT = Path(__file__).resolve().parents[1]


def program(seconds: float) -> str:
    """Back-and-forth moves of 100 mm at 6 m/min with short dwells, about `seconds` long."""
    lines = ["%", "G21 G90 G54 G64"]
    per_cycle = 1.77  # [s] two 100 mm moves at 6 m/min with acceleration, two 0.05 s dwells
    for _ in range(max(1, round(seconds / per_cycle))):
        lines += ["G1 X50 F6000", "G4 P0.05", "G1 X-50", "G4 P0.05"]
    lines += ["M30", "%", ""]
    return "\n".join(lines)


def run(directory: Path, config: Path, name: str, seconds: float, realtime: bool) -> dict:
    prog = directory / f"{name}.ngc"
    prog.write_text(program(seconds))
    args = [
        sys.executable, "-m", "feed_twin.cli", "run", str(prog),
        "--config", str(config), "--out", str(directory / "bags"),
        "--name", name, "--json",
    ]  # fmt: skip
    if realtime:
        args.append("--realtime")
    with reserve_domain_id() as domain:
        env = dict(os.environ)
        env.update(private_graph_env(domain.domain_id))
        proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise SystemExit(f"{name}: feed-twin run failed ({proc.returncode}):\n{proc.stderr}")
    record = json.loads(proc.stdout.strip().splitlines()[-1])
    cpu = {}
    for log in (directory / "bags" / f"{name}.logs").glob("*.log"):
        match = re.search(
            r"^CPU (\S+) [\d.]+ s, ([\d.]+) s after set-up", log.read_text(), re.MULTILINE
        )
        if match:
            cpu[match[1]] = float(match[2])
    record["cpu_s"] = cpu
    steps = record["timing_steps"]
    record["cpu_us_per_exchange"] = {k: round(v / steps * 1e6, 1) for k, v in cpu.items()}
    return record


PROBE = """
import json, sys, time
from feed_twin.ros.dds import apply_scheduling
notes = apply_scheduling(priority=50, cpu_latency_us=0)
seconds, period = float(sys.argv[1]), 1e-3
late = []
deadline = time.monotonic() + period
end = deadline + seconds
while deadline < end:
    time.sleep(max(0.0, deadline - time.monotonic()))
    late.append(time.monotonic() - deadline)
    deadline += period
late.sort()
print(json.dumps({"steps": len(late), "over_1ms": sum(x > 1e-3 for x in late),
                  "p99_ms": late[int(0.99 * len(late))] * 1e3, "max_ms": late[-1] * 1e3,
                  "scheduling": notes}))
"""


def probe(seconds: float) -> dict:
    """The platform's own wake-up lateness at 1 kHz under the sim's real-time settings."""
    proc = subprocess.run(
        [sys.executable, "-c", PROBE, str(seconds)],
        capture_output=True, text=True, timeout=seconds + 60,
    )  # fmt: skip
    if proc.returncode != 0:
        raise SystemExit(f"probe failed ({proc.returncode}):\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--lockstep-seconds", type=float, default=10.0)
    parser.add_argument("--realtime-seconds", type=float, default=60.0)
    parser.add_argument("--probe-seconds", type=float, default=30.0)
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "axis_default.yaml")
    args = parser.parse_args()
    load = os.getloadavg()
    platform = probe(args.probe_seconds) if args.probe_seconds > 0 else {}
    if platform:
        print(
            f"platform: {platform['steps']} wake-ups at 1 kHz with nothing else to do, "
            f"{platform['over_1ms']} more than 1 ms late, p99 {platform['p99_ms']:.3f} ms, "
            f"max {platform['max_ms']:.3f} ms ({'; '.join(platform['scheduling'])})"
        )
    with tempfile.TemporaryDirectory(prefix="nodes_speed_") as tmp:
        directory = Path(tmp)
        lockstep = run(directory, args.config, "lockstep", args.lockstep_seconds, False)
        print(
            f"lockstep: {lockstep['timing_sim_time_s']:.2f} s simulated in "
            f"{lockstep['timing_wall_time_s']:.2f} s, realtime factor "
            f"{lockstep['timing_realtime_factor']:.2f}; CPU per exchange [us] "
            f"{lockstep['cpu_us_per_exchange']}"
        )
        realtime = run(directory, args.config, "realtime", args.realtime_seconds, True)
        print(
            f"realtime: lateness p50 {realtime['timing_lateness_p50_ms']:.3f} ms, p99 "
            f"{realtime['timing_lateness_p99_ms']:.3f} ms, max "
            f"{realtime['timing_lateness_max_ms']:.3f} ms, missed steps "
            f"{realtime['timing_missed_steps']}; CPU per exchange [us] "
            f"{realtime['cpu_us_per_exchange']}"
        )
    print(
        json.dumps(
            {
                "lockstep_realtime_factor": lockstep["timing_realtime_factor"],
                "lockstep_sim_time_s": lockstep["timing_sim_time_s"],
                "lockstep_cpu_s": lockstep["cpu_s"],
                "lockstep_cpu_us_per_exchange": lockstep["cpu_us_per_exchange"],
                "realtime_p99_lateness_ms": realtime["timing_lateness_p99_ms"],
                "realtime_lateness_p50_ms": realtime["timing_lateness_p50_ms"],
                "realtime_lateness_max_ms": realtime["timing_lateness_max_ms"],
                "missed_steps": realtime["timing_missed_steps"],
                "realtime_sim_time_s": realtime["timing_sim_time_s"],
                "realtime_cpu_us_per_exchange": realtime["cpu_us_per_exchange"],
                "probe_steps": platform.get("steps"),
                "probe_late_over_1ms": platform.get("over_1ms"),
                "probe_lateness_max_ms": platform.get("max_ms"),
                "load_average_1min_at_start": load[0],
                "load_average_1min_at_end": os.getloadavg()[0],
                "cores": os.cpu_count(),
            }
        )
    )


if __name__ == "__main__":
    main()
