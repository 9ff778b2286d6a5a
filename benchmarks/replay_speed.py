"""Speed of the shadow twin: replay of a recorded bag, and lag behind a 1 kHz machine.

Figures (last printed line, one JSON object):
- replay_realtime_factor: a 60 s, 1 kHz stand-in recording (config/emps.yaml, AxisCommand +
  JointState, 120 000 messages, Coulomb friction +35 % at 30 s) replayed by
  feed_twin.shadow.replay.replay (read the bag, run the twin, health, metrics); recorded
  seconds per wall-clock second, best of 3 after a warm-up.
- replay_cli_s: wall time of `feed-twin replay` on that bag in a fresh process, including
  Python start-up, writing the comparison bag (240 000 messages), the .rrd and the report.
- shadow_p99_lag_ms, shadow_max_lag_ms: the twin in process (no DDS) beside a machine that
  delivers one command and one measured sample every 1 ms of wall-clock time (paced; the
  stand-in's samples are precomputed so that only the twin's work is timed), 60 s; lag = wall
  time from the arrival of a slot's measured sample to the twin's residual for that slot. It
  includes the one-slot look-ahead the central-difference feed-forward needs (1 ms).
- shadow_dds_p99_lag_ms, shadow_dds_p50_lag_ms: the same lag measured in the twin node over
  DDS, beside the stand-in node in its own process (`feed-twin shadow`, 30 s, 0.2 ms send
  jitter): from a JointState's arrival in the twin node to the TwinResidual of its slot.
- shadow_naming_ms: the cost of one health evaluation that names an effect (ranking the
  effect library on the window), which a live twin pays at most once per window.

    .venv/bin/python benchmarks/replay_speed.py [--duration 60]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from feed_twin.analysis.synthetic import Unmodelled
from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.io.measured import load_column_map
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.replay import replay
from feed_twin.shadow.standin import EFFORT_SAMPLE, StandIn, program_command, record_bag
from feed_twin.shadow.twin import ShadowTwin

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config" / "emps.yaml"
T = 1e-3
F_C = 20.3935


def record(path: Path, duration_s: float) -> Path:
    doc = ModelDoc.load(CONFIG)
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=0.0)
    half = duration_s / 2
    changes = [(half, "friction.F_c_pos", 1.35 * F_C), (half, "friction.F_c_neg", 1.35 * F_C)]
    return record_bag(path, standin, duration_s=duration_s, period_s=T, changes=changes)


def replay_factor(bag: Path, map_path: Path, duration_s: float) -> tuple[float, str]:
    doc = ModelDoc.load(CONFIG)
    cmap = load_column_map(map_path)
    cfg = load_shadow_config(CONFIG)
    result = replay(bag, doc, cmap, cfg)
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        result = replay(bag, doc, cmap, cfg)
        best = min(best, time.perf_counter() - t0)
    return duration_s / best, result.verdicts[-1].message


def cli_seconds(bag: Path, out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "feed_twin.cli", "replay", str(bag), "--config", str(CONFIG),
         "--out", str(out)],
        check=True, capture_output=True,
    )  # fmt: skip
    return time.perf_counter() - t0


def paced_lag(duration_s: float) -> tuple[np.ndarray, int]:
    doc = ModelDoc.load(CONFIG)
    cfg = load_shadow_config(CONFIG)
    t, x, v, a = program_command(duration_s, T)
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=x[0])
    xm, em = standin.step(x, v, a)
    shadow = ShadowTwin(
        Twin.compile(doc), cfg, command_velocity=True, travel_m=0.3, effort_sample=EFFORT_SAMPLE
    )
    n = len(t)
    arrival = np.full(n, np.nan)
    done = np.full(n, np.nan)
    emitted = 0
    start = time.perf_counter() + 0.1
    for k in range(n):
        due = start + k * T
        while (now := time.perf_counter()) < due:
            if due - now > 3e-4:
                time.sleep(due - now - 2e-4)
        arrival[k] = time.perf_counter()
        shadow.push_command(t[k], x[k], v[k])
        shadow.push_measured(t[k], xm[k], em[k])
        block = shadow.process()
        if block is not None:
            finished = time.perf_counter()
            done[emitted : emitted + len(block)] = finished
            emitted += len(block)
    ok = np.isfinite(done)
    return (done[ok] - arrival[ok]) * 1e3, len(shadow.health.verdicts)


def dds_lag(duration_s: float) -> dict:
    from feed_twin.ros.shadow_cli import run_shadow

    with tempfile.TemporaryDirectory() as tmp:
        args = argparse.Namespace(
            config=CONFIG, duration=duration_s, raise_friction_at=None, friction_scale=1.0,
            jitter=2e-4, out=Path(tmp), live=False,
        )  # fmt: skip
        code, report, err = run_shadow(args)
    if code != 0 or report is None:
        raise RuntimeError(f"feed-twin shadow failed (exit {code}):\n{err[-2000:]}")
    return report["lag_ms"]


def naming_ms() -> float:
    from feed_twin.shadow.health import HealthMonitor
    from feed_twin.shadow.twin import physical_effects

    doc = ModelDoc.load(CONFIG)
    cfg = load_shadow_config(CONFIG)
    twin = Twin.compile(doc)
    t, x, v, a = program_command(cfg.window_s + cfg.baseline_s, T)
    rng = np.random.default_rng(0)
    effort_dev = 0.5 * rng.standard_normal(len(t))
    health = HealthMonitor(
        cfg, physical=physical_effects(twin), effort_unit="N", lead_m=twin.lead_m,
        pole_pairs=None, travel_m=0.3,
    )  # fmt: skip
    effort_twin = 95.0 * a + 203.5 * v + F_C * np.tanh(v / 1e-3)  # rigid body with friction
    rows = np.column_stack([t, x, 1e-7 * rng.standard_normal(len(t)), effort_dev, effort_twin])
    health.update(rows, valid=np.ones(len(t), dtype=bool))
    window = health._window.data
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        health._name_effect(window)
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="recording length [s]")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "run"
        map_path = record(bag, args.duration)
        factor, last = replay_factor(bag, map_path, args.duration)
        print(f"replay: {factor:.1f}x real time; last verdict: {last}")
        cli = cli_seconds(bag, Path(tmp) / "out")
        print(f"feed-twin replay (fresh process, all outputs): {cli:.2f} s")
    lag, verdicts = paced_lag(args.duration)
    p50, p99, worst = np.percentile(lag, 50), np.percentile(lag, 99), float(np.max(lag))
    print(f"shadow lag at 1 kHz ({len(lag)} slots, {verdicts} verdicts): p50 {p50:.3f} ms, "
          f"p99 {p99:.3f} ms, max {worst:.3f} ms")  # fmt: skip
    dds = dds_lag(min(args.duration, 30.0))
    print(f"shadow lag over DDS: p50 {dds['p50']:.3f} ms, p99 {dds['p99']:.3f} ms, "
          f"max {dds['max']:.3f} ms")  # fmt: skip
    naming = naming_ms()
    print(f"one naming evaluation: {naming:.1f} ms")
    print(
        json.dumps(
            {
                "replay_realtime_factor": round(factor, 1),
                "replay_cli_s": round(cli, 2),
                "shadow_p99_lag_ms": round(float(p99), 3),
                "shadow_max_lag_ms": round(worst, 3),
                "shadow_dds_p50_lag_ms": round(dds["p50"], 3),
                "shadow_dds_p99_lag_ms": round(dds["p99"], 3),
                "shadow_naming_ms": round(naming, 1),
                "duration_s": args.duration,
            }
        )
    )


if __name__ == "__main__":
    main()
