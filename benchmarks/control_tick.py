"""Cost of one `cascade_tick` inside a compiled loop (what the engine pays per base tick).

Runs the machine-tool controller (3 loops, 16/8/4 kHz, FOC + SVPWM) and the EMPS controller
against a precomputed rotating measurement for 200 000 base ticks, after a warm-up call; the
same loop without the controller is subtracted (best of 5 each).
Last printed line: one JSON object of the figures (ns per tick).

    .venv/bin/python benchmarks/control_tick.py
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from numba import njit

from feed_twin.control.cascade import cascade_tick
from feed_twin.control.config import load_controller_config
from feed_twin.control.layout import build_cascade
from feed_twin.core import signals as sig
from feed_twin.core.config import load_yaml

FIXTURES = Path(__file__).resolve().parent.parent / "tests" / "fixtures"


# not cached: numba does not invalidate a cache when a callee in another module changes
@njit
def _loop(cp, cs, period_s, signals, run_controller):
    """signals: (n, 5) rows of encoder angle, scale position, i_a, i_b, i_c, precomputed."""
    ref = np.zeros(sig.REF_SIZE)
    meas = np.zeros(sig.MEAS_SIZE)
    out = np.zeros(sig.OUT_SIZE)
    meas[sig.MEAS_U_DC_V] = 560.0
    acc = 0.0
    for k in range(signals.shape[0]):
        ref[sig.REF_POS_M] = 0.01 * k * period_s
        ref[sig.REF_VEL_M_S] = 0.01
        meas[sig.MEAS_THETA_ENC_RAD] = signals[k, 0]
        meas[sig.MEAS_X_SCALE_M] = signals[k, 1]
        meas[sig.MEAS_I_A] = signals[k, 2]
        meas[sig.MEAS_I_B] = signals[k, 3]
        meas[sig.MEAS_I_C] = signals[k, 4]
        if run_controller:
            cascade_tick(cp, cs, k, ref, meas, out)
        acc += out[sig.OUT_DUTY_A] + out[sig.OUT_EFFORT_CMD] + meas[sig.MEAS_I_A] + ref[0]
    return acc


def _ns_per_tick(name: str, n: int = 200_000) -> float:
    """Best of 5 of the loop with the controller minus the same loop without it."""
    path = FIXTURES / name
    cascade = build_cascade(load_controller_config(load_yaml(path)["controller"], str(path)))
    T = cascade.base_period_s
    t = np.arange(n) * T
    signals = np.column_stack(
        [
            6.28 * t,
            0.01 * t - 1e-5,
            np.sin(25.0 * t),
            np.sin(25.0 * t - 2.094),
            -np.sin(25.0 * t) - np.sin(25.0 * t - 2.094),
        ]
    )
    per_tick = {}
    for run_controller in (False, True):
        _loop(cascade.params, cascade.initial_state(), T, signals[:10], run_controller)
        best = math.inf
        for _ in range(5):
            cs = cascade.initial_state()
            t0 = time.perf_counter()
            _loop(cascade.params, cs, T, signals, run_controller)
            best = min(best, (time.perf_counter() - t0) / n)
        per_tick[run_controller] = best
    return (per_tick[True] - per_tick[False]) * 1e9


def main() -> None:
    figures = {
        "axis_3loops_foc_ns_per_tick": round(_ns_per_tick("controller_axis.yaml"), 1),
        "emps_ns_per_tick": round(_ns_per_tick("controller_emps.yaml"), 1),
    }
    for key, value in figures.items():
        print(f"{key}: {value}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
