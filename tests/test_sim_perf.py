"""What the engine's speed-ups must not change: noise drawn per tick in chunks, parameters as a
tuple."""

import importlib
import pkgutil

import numpy as np
from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher

import feed_twin.control
import feed_twin.core
import feed_twin.plant
from feed_twin.core import signals as sig
from feed_twin.sim.config import build_engine, load_axis_config


def test_noisy_axis_in_chunks_is_bit_identical_to_one_run():
    axis = load_axis_config("config/axis_default.yaml")
    h = axis.engine.base_period_s
    sizes = (1, 30, 33, 64, 71)
    n = sum(sizes)
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = 1e-4
    one = build_engine(axis, output_period_s=h).run(n, ref=ref)
    engine = build_engine(axis, output_period_s=h)
    parts, start = [], 0
    for size in sizes:
        parts.append(engine.advance(size, ref=ref[start : start + size]))
        start += size
    chunks = type(one).concat(parts)
    assert np.array_equal(one.data, chunks.data)
    # the noise is really there: the measured phase current is off the true one by about the
    # noise standard deviation 0.02 A (plus the 100 A / 4096 ADC step), not by zero
    error = one["meas.i_a_meas_A"] - one["motor.i_a"]
    assert 0.01 < np.std(error) < 0.04


def test_tuple_rhs_of_the_loop_equals_the_array_rhs_with_energy_states():
    axis = load_axis_config("config/axis_default.yaml")
    model = axis.plant.with_energy_tracking()
    ns = model.namespace()
    x = model.initial_state().copy()
    x[: len(x)] += np.linspace(0.01, 0.2, len(x))  # every state off its rest value
    p = model.nominal_params()
    out = np.zeros(sig.OUT_SIZE)
    out[sig.OUT_ENABLED] = 1.0
    out[sig.OUT_DUTY_A], out[sig.OUT_DUTY_B], out[sig.OUT_DUTY_C] = 0.6, 0.45, 0.4
    ext = np.array([150.0])
    dx = np.full(len(x), np.nan)
    ns["rhs"](0.0, x, p, out, ext, np.zeros(3), dx)
    trig = ns["angles"](0.0, x, p)  # of the same state: the tick's first RK4 stage
    derivatives = ns["rhs_tuple_start"](0.0, tuple(x), tuple(p), out, ext, np.zeros(3), trig)
    assert len(model.state_names) > 12  # energy accumulators included
    assert np.array_equal(np.array(derivatives), dx)
    # a later stage: the rotor has turned 0.2 rad (electrical) since the tick's start, and the
    # pair is rotated from there, to within rounding of the sine and cosine evaluated anew
    later = x.copy()
    later[model.state_index["motor.phi"]] += 0.2 / p[model.param_index["motor.p"]]
    ns["rhs"](0.0, later, p, out, ext, np.zeros(3), dx)
    derivatives = ns["rhs_tuple"](0.0, tuple(later), tuple(p), out, ext, np.zeros(3), trig)
    np.testing.assert_allclose(np.array(derivatives), dx, rtol=1e-12, atol=1e-12)
    assert not np.array_equal(np.array(derivatives), dx)  # rotated, not evaluated anew


def test_the_laws_the_kernel_calls_are_not_disk_cached():
    """numba caches machine code only: a law loaded from the disk cache is called, not inlined,
    by a kernel compiled later (350 instead of 300 ns per tick). So every numba function of the
    plant and the controller is either compiled in process (no cache) and marked `forceinline`
    (LLVM's alwaysinline: 7 % faster again, no compile-time cost) or inlined by numba itself;
    only `cascade_tick`, called once per tick and from the controller node, is cached, and the
    rare fallbacks (the noise's ziggurat tail, sincos_near's full evaluation) stay out of line."""
    entry_points = {
        "feed_twin.control.cascade.cascade_tick",
        "feed_twin.core.smooth._smooth_sign_flat",  # the analysis code's, not the kernel's
    }
    out_of_line = {"feed_twin.plant.noise._slow_path", "feed_twin.core.trig._sincos_far"}
    seen = []
    for pkg in (feed_twin.core, feed_twin.plant, feed_twin.control):
        for info in pkgutil.iter_modules(pkg.__path__):
            module = importlib.import_module(f"{pkg.__name__}.{info.name}")
            for name, obj in vars(module).items():
                if not isinstance(obj, Dispatcher) or obj.py_func.__module__ != module.__name__:
                    continue
                full = f"{module.__name__}.{name}"
                seen.append(full)
                if full in entry_points or obj.targetoptions.get("inline") == "always":
                    continue
                # numba's Dispatcher keeps its cache in a private attribute its stubs omit
                cache = obj._cache  # pyright: ignore[reportAttributeAccessIssue]
                assert isinstance(cache, NullCache), f"{full} is cached on disk"
                if full not in out_of_line:
                    assert obj.targetoptions.get("forceinline"), f"{full} is not forceinline"
    assert "feed_twin.plant.pmsm.pmsm_dq" in seen
    assert "feed_twin.control.cascade.current_law" in seen
