"""Set-up and messaging figures: the no-op set-up time and the DDS round trip of every message.

Runs `tools/setup.sh` a few times on an up-to-date checkout (the cost `make test` and `make demo`
pay before their job) and `feed-twin msgs-check --json` once. The last line is one JSON object:
noop_setup_s (median wall time), msgs_roundtrip_ms_max (slowest publish -> callback of the
eight message types, two nodes in one process), msgs_failed (types that did not come back
intact, in one process or from a child process).
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RUNS = 5


def main() -> int:
    subprocess.run(["bash", str(REPO / "tools" / "setup.sh")], check=True, capture_output=True)
    durations = []
    for _ in range(RUNS):
        start = time.perf_counter()
        result = subprocess.run(
            ["bash", str(REPO / "tools" / "setup.sh")], check=True, capture_output=True, text=True
        )
        durations.append(time.perf_counter() - start)
        if "up to date" not in result.stdout:
            print(f"set-up was not a no-op: {result.stdout.strip()}", file=sys.stderr)
            return 1
    check = subprocess.run(
        [str(Path(sys.prefix) / "bin" / "feed-twin"), "msgs-check", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    figures = json.loads(check.stdout.strip().splitlines()[-1])
    print(check.stdout.strip().splitlines()[0])
    print(f"no-op set-up: median {statistics.median(durations) * 1e3:.1f} ms over {RUNS} runs")
    print(
        json.dumps(
            {
                "noop_setup_s": round(statistics.median(durations), 4),
                "msgs_roundtrip_ms_max": round(max(figures["latency_ms"].values()), 3),
                "msgs_failed": figures["failed_one_process"] + figures["failed_two_processes"],
            }
        )
    )
    return check.returncode


if __name__ == "__main__":
    sys.exit(main())
