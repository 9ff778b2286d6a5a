"""One process's cold start and per-tick CPU time of config/axis_default.yaml, for
benchmarks/before_after.py, which runs it under each tree (cwd = the tree, PYTHONPATH = the tree).

Printed as one JSON object: import_s (feed_twin's engine modules), build_s (load the axis file,
build the engine, kernel loaded from numba's cache), first_run_s (the first 1 s of model_speed's
trapezoid), and the best of REPEATS runs of that 1 s in process CPU time per base tick, with the
controller's structure compiled in (ns_per_tick) and with every parameter
(ns_per_tick_inline); model_speed's batch (1000 sets, 0.2 s each, all threads), the best of
BATCH_REPEATS in process CPU time per set and tick (batch_ns_per_set_tick).
"""

import time

t0 = time.perf_counter()
import dataclasses  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402

try:
    from feed_twin.core import signals as sig
except ImportError:  # a tree from before the core layer (pyright reads this one: no module)
    from feed_twin.control import signals as sig  # pyright: ignore[reportAttributeAccessIssue]
from feed_twin.sim.batch import run_batch  # noqa: E402
from feed_twin.sim.config import build_engine, load_axis_config  # noqa: E402

REPEATS = 25
BATCH_SETS = 1000
BATCH_REPEATS = 3

t1 = time.perf_counter()
axis = load_axis_config("config/axis_default.yaml")
engine = build_engine(axis)
t2 = time.perf_counter()
n = round(1.0 / engine.h)
h = engine.h
t = np.arange(n) * h
v = np.minimum(np.minimum(2.0 * t, 2.0 * (n * h - 0.05 - t)), 0.1).clip(0.0)
ref = np.zeros((n, sig.REF_SIZE))  # model_speed.trapezoid
ref[:, sig.REF_VEL_M_S] = v
ref[:, sig.REF_POS_M] = np.cumsum(v) * h
ref[:, sig.REF_ACC_M_S2] = np.gradient(v, h)
engine.run(n, ref=ref)
t3 = time.perf_counter()
out = {"import_s": t1 - t0, "build_s": t2 - t1, "first_run_s": t3 - t2}
for inline in (False, True):
    config = dataclasses.replace(axis.engine, inline_parameters=inline)
    run = build_engine(dataclasses.replace(axis, engine=config))
    run.run(n, ref=ref)
    best = float("inf")
    for _ in range(REPEATS):
        c0 = time.process_time()
        run.run(n, ref=ref)
        best = min(best, time.process_time() - c0)
    out["ns_per_tick_inline" if inline else "ns_per_tick"] = best / n * 1e9
# model_speed.batch_rate's batch: 1000 sets (table mass varied), 0.2 s at 0.05 m/s each
batch_engine = build_engine(axis, record=["table.s"], output_period_s=0.01)
nb = round(0.2 / h)
vb = np.minimum(np.minimum(2.0 * t[:nb], 2.0 * (nb * h - 0.05 - t[:nb])), 0.05).clip(0.0)
ref_b = np.zeros((nb, sig.REF_SIZE))
ref_b[:, sig.REF_VEL_M_S] = vb
ref_b[:, sig.REF_POS_M] = np.cumsum(vb) * h
ref_b[:, sig.REF_ACC_M_S2] = np.gradient(vb, h)
P = np.tile(axis.plant.nominal_params(), (BATCH_SETS, 1))
P[:, axis.plant.param_index["table.m"]] = np.linspace(150.0, 250.0, BATCH_SETS)
axis.plant.fill_derived(P)
best = float("inf")
for _ in range(BATCH_REPEATS):  # the first is also the warm-up
    c0 = time.process_time()
    run_batch(batch_engine, P, nb, ref=ref_b)
    best = min(best, time.process_time() - c0)
out["batch_ns_per_set_tick"] = best / (BATCH_SETS * nb) * 1e9
print(json.dumps({k: round(value, 4 if k.endswith("_s") else 2) for k, value in out.items()}))
