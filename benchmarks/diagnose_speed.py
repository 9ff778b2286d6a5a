"""Wall time of the whole EMPS diagnosis (identify on DATA_EMPS.csv, validate on the PULSES run).

Runs `feed-twin diagnose` in-process once after a warm-up that compiles every kernel structure
the diagnosis meets (numba's disk cache makes later processes start warm), then times it; also
reports the validation errors so a speed-up that breaks the result is visible.
Last printed line: one JSON object of the figures.

    .venv/bin/python benchmarks/diagnose_speed.py
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

from feed_twin.cli import main

ROOT = Path(__file__).resolve().parent.parent
EMPS = Path("/work/shared/data/emps")


def run(out: Path) -> float:
    start = time.perf_counter()
    code = main(
        [
            "diagnose",
            str(EMPS / "DATA_EMPS.csv"),
            "--config", str(ROOT / "config" / "emps_nominal.yaml"),
            "--map", str(ROOT / "config" / "emps_map.yaml"),
            "--validate", str(EMPS / "DATA_EMPS_PULSES.csv"),
            "--out", str(out),
        ]
    )  # fmt: skip
    if code != 0:
        raise SystemExit(f"diagnose failed with exit code {code}")
    return time.perf_counter() - start


def main_() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        warm = run(Path(tmp) / "warm")
        seconds = run(Path(tmp) / "timed")
        report = json.loads((Path(tmp) / "timed" / "report.json").read_text())
    v = report["validation"]["after"]
    figures = {
        "emps_diagnose_s": round(seconds, 2),
        "emps_diagnose_first_s": round(warm, 2),
        "emps_effects": [e["name"] for e in report["effects"]],
        "emps_validation_force_rel_err_pct": round(v["effort_rel_err_pct"], 3),
        "emps_validation_position_rel_err_pct": round(v["pos_rel_err_pct"], 5),
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main_()
