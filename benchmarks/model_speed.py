"""Speed of the compiled engine: realtime factor, batch throughput, against solve_ivp, cold start.

Figures (last printed line, one JSON object):
- realtime_factor: config/axis_default.yaml closed loop (position, velocity and current loops,
  averaged inverter, 16 kHz), a 1 s trapezoidal move (0.1 m/s, 2 m/s^2), one thread, after a
  warm-up run; best of REPEATS; simulated seconds per wall-clock second (realtime_factor_median:
  their median). realtime_factor_cpu: the best per second of process CPU time, which other jobs
  on shared cores do not inflate (load_average_1min says how shared they were). Best of many:
  on the project's virtual machines the host slows a run by a third for a fraction of a second
  to several seconds at a time, whatever runs in the guest (docs/architecture.md).
- realtime_factor_inlined (and _cpu, _median): the same with engine.inline_parameters (the
  parameter values compiled into the kernel: what a long run of one parameter set can choose).
- c_realtime_factor (and _median, _cpu): the C kernel (feed_twin.native: the same plant and
  controller translated from the numba kernel's functions, compiled with the system cc) on the
  same move, each repeat right after a numba repeat (c_numba_realtime_factor: numba's best of
  those same interleaved repeats, so that both saw the same load); the two end in the same state,
  bit for bit (checked); c_numba_realtime_factor_median and _cpu: numba's median and best per
  CPU second in those repeats. `--native-only` measures only this pair.
- batch_axis_seconds_per_second: 1000 parameter sets of the same axis (table mass varied),
  0.2 s of the same move each, advanced in parallel (run_batch: one thread per usable core, the
  kernel releases the GIL), best of two runs (the first is also the warm-up);
  batch_axis_seconds_per_cpu_second: the same per CPU second of all threads (equal to the
  wall-clock rate when only one core was free).
- solve_ivp_ratio: wall time of feed_twin.sim.reference (the same generated plant functions,
  called from Python under scipy solve_ivp DOP853 per controller tick, after a warm-up) over the
  kernel's, per simulated second, on 20 ms of the move.
- first_run_s: a fresh Python process that loads the config, builds the engine and simulates
  1 s, with numba's on-disk cache warm (the script runs it twice and reports the second).
- motulator_ratio: motulator (PyPI, Python 3.12, in its own venv under the cache directory)
  simulating a comparable drive (PMSM, current + speed control, two-mass mechanics, 62.5 us
  sampling) for 1 s, its wall time over ours for 1 s; null with the reason when it cannot run.

    .venv/bin/python benchmarks/model_speed.py [--skip-motulator]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from feed_twin.core import signals as sig
from feed_twin.sim.batch import run_batch
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.kernel import cache_dir
from feed_twin.sim.reference import reference_run

ROOT = Path(__file__).resolve().parent.parent
AXIS = ROOT / "config" / "axis_default.yaml"
PY312 = Path("/root/.pyenv/versions/3.12.1/bin/python3.12")


def trapezoid(n: int, h: float, v_max: float = 0.1, a_max: float = 2.0) -> np.ndarray:
    t = np.arange(n) * h
    t_end = n * h
    v = np.minimum(np.minimum(a_max * t, a_max * (t_end - 0.05 - t)), v_max).clip(0.0)
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_VEL_M_S] = v
    ref[:, sig.REF_POS_M] = np.cumsum(v) * h
    ref[:, sig.REF_ACC_M_S2] = np.gradient(v, h)
    return ref


def best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def best_cpu_of(fn, repeats: int) -> float:
    """Best process CPU time of `fn`: on shared cores the wall clock also counts the others."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


REPEATS = 15


def realtime_factor(axis, *, inline: bool = False) -> tuple[float, float, float, float]:
    """(best wall rate, its 1 s wall time, median wall rate, best CPU rate)."""
    engine_config = dataclasses.replace(axis.engine, inline_parameters=inline)
    engine = build_engine(dataclasses.replace(axis, engine=engine_config))
    n = round(1.0 / engine.h)
    ref = trapezoid(n, engine.h)
    engine.run(n, ref=ref)
    walls = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        engine.run(n, ref=ref)
        walls.append(time.perf_counter() - t0)
    cpu = best_cpu_of(lambda: engine.run(n, ref=ref), REPEATS)
    return 1.0 / min(walls), min(walls), 1.0 / float(np.median(walls)), 1.0 / cpu


def c_realtime_factor(axis) -> dict[str, float]:
    """C and numba, interleaved: best wall rate, median wall rate, best CPU rate of each."""
    from feed_twin.native.build import CModel, c_kernel_for_axis, compile_kernel

    kernel = c_kernel_for_axis(axis)
    model = CModel(compile_kernel(kernel), kernel)
    engine = build_engine(axis)
    n = round(1.0 / engine.h)
    ref = trapezoid(n, engine.h)
    engine.run(n, ref=ref)

    def c_run() -> None:
        model.reset()
        model.run(n, ref=ref, every=0)

    c_run()
    if not np.array_equal(model.states(), engine.x):
        raise RuntimeError("the C kernel ended in another state than the numba kernel")
    c_walls, numba_walls, c_cpu, numba_cpu = [], [], float("inf"), float("inf")
    for _ in range(REPEATS):
        numba_walls.append(best_of(lambda: engine.run(n, ref=ref), 1))
        c_walls.append(best_of(c_run, 1))
        numba_cpu = min(numba_cpu, best_cpu_of(lambda: engine.run(n, ref=ref), 1))
        c_cpu = min(c_cpu, best_cpu_of(c_run, 1))
    return {
        "c_realtime_factor": 1.0 / min(c_walls),
        "c_realtime_factor_median": 1.0 / float(np.median(c_walls)),
        "c_realtime_factor_cpu": 1.0 / c_cpu,
        "c_numba_realtime_factor": 1.0 / min(numba_walls),
        "c_numba_realtime_factor_median": 1.0 / float(np.median(numba_walls)),
        "c_numba_realtime_factor_cpu": 1.0 / numba_cpu,
    }


def batch_rate(axis, n_sets: int = 1000, duration: float = 0.2) -> tuple[float, float]:
    engine = build_engine(axis, record=["table.s"], output_period_s=0.01)
    n = round(duration / engine.h)
    ref = trapezoid(n, engine.h, v_max=0.05)
    plant = axis.plant
    masses = np.linspace(150.0, 250.0, n_sets)
    P = np.tile(plant.nominal_params(), (n_sets, 1))
    P[:, plant.param_index["table.m"]] = masses
    plant.fill_derived(P)
    run_batch(engine, P[:4], 16, ref=ref[:16])  # compile
    best_wall, best_cpu = float("inf"), float("inf")
    for _ in range(2):  # the first run of the 1000 sets is also their warm-up (about 10 % slower)
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_batch(engine, P, n, ref=ref)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if res.diverged.any():
            raise RuntimeError(f"batch: {res.diverged.sum()} sets diverged: {res.messages[0]}")
        best_wall, best_cpu = min(best_wall, wall), min(best_cpu, cpu)
    return n_sets * duration / best_wall, n_sets * duration / best_cpu


def solve_ivp_ratio(axis) -> float:
    engine = build_engine(axis, output_period_s=1e-3)
    n = round(0.02 / engine.h)
    ref = trapezoid(n, engine.h)
    engine.run(n, ref=ref)
    fast = best_of(lambda: engine.run(n, ref=ref), 3)
    # warm-up: the plant laws are compiled in process (not disk-cached), once per process
    reference_run(engine, 2, ref=ref[:2], rtol=1e-8, atol=1e-10)
    t0 = time.perf_counter()
    reference_run(engine, n, ref=ref, rtol=1e-8, atol=1e-10)
    slow = time.perf_counter() - t0
    return slow / fast


FIRST_RUN = """
import time
t0 = time.perf_counter()
import numpy as np
from feed_twin.core import signals as sig
from feed_twin.sim.config import build_engine, load_axis_config
axis = load_axis_config({path!r})
engine = build_engine(axis)
n = round(1.0 / engine.h)
ref = np.zeros((n, sig.REF_SIZE))
ref[:, sig.REF_POS_M] = 0.01
engine.run(n, ref=ref)
print(time.perf_counter() - t0)
"""


def first_run_s() -> float:
    code = FIRST_RUN.format(path=str(AXIS))
    walls = []
    for _ in range(2):  # the first fills the cache if it is cold
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, cwd=ROOT)
        walls.append(time.perf_counter() - t0)
    return walls[-1]


MOTULATOR_SCRIPT = ROOT / "benchmarks" / "_motulator_drive.py"


def motulator_wall() -> tuple[float | None, str]:
    """Wall time of 1 s of the comparable motulator drive, or (None, reason)."""
    if not PY312.exists():
        return None, f"{PY312} not found (motulator needs Python >= 3.12)"
    venv = cache_dir().parent / "motulator-venv"
    python = venv / "bin" / "python"
    try:
        if not python.exists():
            subprocess.run([str(PY312), "-m", "venv", str(venv)], check=True, capture_output=True)
        probe = subprocess.run([str(python), "-c", "import motulator"], capture_output=True)
        if probe.returncode != 0:
            subprocess.run(
                [str(python), "-m", "pip", "install", "--quiet", "motulator"],
                check=True,
                capture_output=True,
                timeout=600,
            )
        out = subprocess.run(
            [str(python), str(MOTULATOR_SCRIPT)],
            check=True,
            capture_output=True,
            text=True,
            timeout=1800,
        )
    except subprocess.CalledProcessError as exc:
        tail = exc.stderr or b""
        tail = tail.decode() if isinstance(tail, bytes) else tail
        return (
            None,
            f"motulator run failed: {tail.strip().splitlines()[-1] if tail.strip() else exc}",
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"motulator unavailable: {exc}"
    return float(out.stdout.strip().splitlines()[-1]), ""


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--skip-motulator", action="store_true")
    parser.add_argument("--native-only", action="store_true", help="only C next to numba")
    args = parser.parse_args()
    axis = load_axis_config(AXIS)
    native = {key: round(value, 2) for key, value in c_realtime_factor(axis).items()}
    print(
        f"C kernel {native['c_realtime_factor']:.1f} (median "
        f"{native['c_realtime_factor_median']:.1f}, {native['c_realtime_factor_cpu']:.1f} per CPU "
        f"second), numba {native['c_numba_realtime_factor']:.1f} (median "
        f"{native['c_numba_realtime_factor_median']:.1f}, "
        f"{native['c_numba_realtime_factor_cpu']:.1f} per CPU second) in the same interleaved "
        "repeats"
    )
    if args.native_only:
        native["load_average_1min"] = round(os.getloadavg()[0], 2)
        print(json.dumps(native))
        return 0
    rtf, wall_1s, rtf_median, rtf_cpu = realtime_factor(axis)
    print(
        f"realtime factor {rtf:.1f} (1 s in {wall_1s * 1e3:.1f} ms; median {rtf_median:.1f}), "
        f"{rtf_cpu:.1f} per CPU second"
    )
    inl, _, inl_median, inl_cpu = realtime_factor(axis, inline=True)
    print(
        f"with inline_parameters {inl:.1f} (median {inl_median:.1f}), {inl_cpu:.1f} per CPU second"
    )
    batch, batch_cpu = batch_rate(axis)
    print(
        f"batch {batch:.1f} axis-seconds per second (1000 sets, {os.cpu_count()} cores), "
        f"{batch_cpu:.1f} per CPU second"
    )
    ratio = solve_ivp_ratio(axis)
    print(f"solve_ivp reference is {ratio:.0f}x slower")
    first = first_run_s()
    print(f"cold process, warm cache: {first:.2f} s")
    figures = {
        "realtime_factor": round(rtf, 2),
        "realtime_factor_median": round(rtf_median, 2),
        "realtime_factor_cpu": round(rtf_cpu, 2),
        "realtime_factor_inlined": round(inl, 2),
        "realtime_factor_inlined_median": round(inl_median, 2),
        "realtime_factor_inlined_cpu": round(inl_cpu, 2),
        **native,
        "batch_axis_seconds_per_second": round(batch, 2),
        "batch_axis_seconds_per_cpu_second": round(batch_cpu, 2),
        "load_average_1min": round(os.getloadavg()[0], 2),
        "solve_ivp_ratio": round(ratio, 1),
        "first_run_s": round(first, 3),
        "motulator_ratio": None,
        "motulator_reason": "skipped (--skip-motulator)",
        "cores": os.cpu_count(),
    }
    if not args.skip_motulator:
        wall, reason = motulator_wall()
        figures["motulator_ratio"] = None if wall is None else round(wall / wall_1s, 1)
        figures["motulator_reason"] = reason or None
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
