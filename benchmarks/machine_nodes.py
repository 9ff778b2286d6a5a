"""Speed of the machine's node set (issue 18): the last printed line is one JSON object.

- lockstep_realtime_factor: `feed-twin run PROGRAM --config config/machine_default.yaml`, the
  three linear axes each with a sim and a controller node in its own process, one G-code node,
  one recorder (eight processes), 1 kHz exchange, in lockstep: simulated time over the wall
  time of the first axis's sim from its first to its last exchange (goal >= 2 on this 2-core
  machine).
- cpu_us_per_exchange: per node process its CPU time after set-up (numba compilation and DDS
  discovery excluded) per exchange; comparable on a busy machine, where the wall-clock figure
  is not. Also the load average at the start and the end.
- with `--realtime-seconds S` (default 0: skipped), the same machine under `--realtime`:
  lateness p50/p99/max of the first axis's exchanges and its missed steps.

    .venv/bin/python benchmarks/machine_nodes.py [--lockstep-seconds 10] [--realtime-seconds 0]
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
MACHINE = ROOT / "config" / "machine_default.yaml"


def program(seconds: float) -> str:
    """Moves of all three linear axes at once (100 x 60 x 40 mm at 6 m/min), about `seconds`."""
    lines = ["%", "G21 G90 G54 G64", "G1 X0 Y0 Z100 F6000"]
    per_cycle = 2.6  # [s] two moves of 124 mm at 6 m/min with acceleration, two 0.05 s dwells
    for _ in range(max(1, round(seconds / per_cycle))):
        lines += ["G1 X100 Y60 Z140", "G4 P0.05", "G1 X0 Y0 Z100", "G4 P0.05"]
    lines += ["M30", "%", ""]
    return "\n".join(lines)


def run(directory: Path, name: str, seconds: float, realtime: bool) -> dict:
    prog = directory / f"{name}.ngc"
    prog.write_text(program(seconds))
    args = [
        sys.executable, "-m", "feed_twin.cli", "run", str(prog), "--config", str(MACHINE),
        "--out", str(directory / "bags"), "--name", name, "--json",
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
    steps = record["timing_steps"]
    cpu = {}
    for log in sorted((directory / "bags" / f"{name}.logs").glob("*.log")):
        match = re.search(r"^CPU \S+ [\d.]+ s, ([\d.]+) s after set-up", log.read_text(), re.M)
        if match:
            cpu[log.stem] = round(float(match[1]) / steps * 1e6, 1)
    record["cpu_us_per_exchange"] = cpu
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lockstep-seconds", type=float, default=10.0)
    parser.add_argument("--realtime-seconds", type=float, default=0.0)
    args = parser.parse_args()
    result: dict[str, object] = {"load_start": os.getloadavg()[0], "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory(prefix="machine_nodes_") as tmp:
        directory = Path(tmp)
        run(directory, "warm", 0.5, False)  # compiles and caches every axis's kernels
        lock = run(directory, "lockstep", args.lockstep_seconds, False)
        result.update({
            "lockstep_realtime_factor": lock["timing_realtime_factor"],
            "lockstep_steps": lock["timing_steps"],
            "cpu_us_per_exchange": lock["cpu_us_per_exchange"],
            "contour_error_max_m": lock["contour_error_max_m"],
            "following_error_max_m": lock["following_error_max_m"],
        })  # fmt: skip
        print(f"lockstep: {lock['timing_realtime_factor']:.2f}x real time, CPU per exchange "
              f"[us]: {lock['cpu_us_per_exchange']}")  # fmt: skip
        if args.realtime_seconds > 0:
            rt = run(directory, "realtime", args.realtime_seconds, True)
            for key in ("lateness_p50_ms", "lateness_p99_ms", "lateness_max_ms", "missed_steps"):
                result[f"realtime_{key}"] = rt.get(f"timing_{key}")
            result["realtime_steps"] = rt["timing_steps"]
            print(f"realtime: {json.dumps({k: v for k, v in result.items() if 'realtime_' in k})}")
    result["load_end"] = os.getloadavg()[0]
    print(json.dumps(result))


if __name__ == "__main__":
    main()
