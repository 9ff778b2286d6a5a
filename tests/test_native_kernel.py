"""The C kernel against the numba kernel: one source of physics, two backends, the same doubles.

Both run the same whole program (tests/fixtures/gcode/sample.ngc, 7.1 s) from the same state;
every recorded signal (states, auxiliaries, sensor samples, controller outputs and states) is
compared every millisecond. The operations are the same, in the same order, without fused
multiply-adds the source does not spell: the results are bit-identical, and the test asserts
1e-12 of each signal's range so that it names the signal if they ever drift apart.
"""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from native_support import ROOT, SAMPLE, program_ref

from feed_twin.core import signals
from feed_twin.core.config import load_yaml
from feed_twin.native.build import (
    FLAGS,
    CModel,
    CompilerMissingError,
    c_kernel_for_axis,
    compile_kernel,
    find_cc,
    run_cc,
)
from feed_twin.native.ckinds import DOUBLE, INT, PRELUDE, ArrayKind
from feed_twin.native.translate import Source, TranslationError, Translator
from feed_twin.sim.config import build_engine, load_axis_config


def _switching_axis():
    raw = load_yaml(ROOT / "config" / "axis_default.yaml")
    for comp in raw["plant"]["components"]:
        if comp["name"] == "inverter":
            comp["params"]["model"] = "switching"
    return load_axis_config(raw, source="axis_default.yaml with a switching inverter")


def _compare(axis, seconds: float | None = None) -> None:
    ref = program_ref(SAMPLE, axis.engine.base_period_s)
    if seconds is not None:
        ref = ref[: round(seconds / axis.engine.base_period_s)]
    every = max(1, round(1e-3 / axis.engine.base_period_s))
    engine = build_engine(axis, output_period_s=every * axis.engine.base_period_s)
    x0 = axis.plant.initial_state({"table": float(ref[0, signals.REF_POS_M])})
    engine.reset(x0=x0)
    expected = engine.advance(len(ref), ref=ref)
    kernel = c_kernel_for_axis(axis)
    model = CModel(compile_kernel(kernel), kernel)
    model.set_states(x0)
    got = model.run(len(ref), ref=ref, every=every)
    assert kernel.record_names == expected.names
    assert got.shape == expected.data.shape
    span = np.maximum(np.abs(expected.data).max(axis=0), 1e-300)
    worst = np.abs(got - expected.data).max(axis=0) / span
    i = int(np.argmax(worst))
    assert worst[i] <= 1e-12, f"{kernel.record_names[i]}: relative deviation {worst[i]:.3g}"
    # the move happened: the table travelled the program's X range
    s = expected["table.s"]
    assert s.max() - s.min() > 0.03


def test_axis_default_c_kernel_equals_numba_over_a_whole_program():
    _compare(load_axis_config(ROOT / "config" / "axis_default.yaml"))


@pytest.mark.slow
def test_cubic_interpolation_and_feed_forward_at_the_velocity_rate_in_c():
    """The truth-nominal drive's setpoint path (feed_twin.control.cascade: `hermite`,
    `refresh_feed_forward`) on the default axis, whose position loop runs at half its
    velocity loop's rate."""
    raw = load_yaml(ROOT / "config" / "axis_default.yaml")
    raw["controller"]["position"] |= {"interpolation": "cubic", "feed_forward_rate": "velocity"}
    _compare(load_axis_config(raw, source="axis_default.yaml, cubic, feed-forward at 8 kHz"), 1.0)


def test_emps_c_kernel_equals_numba_over_a_whole_program():
    _compare(load_axis_config(ROOT / "config" / "emps.yaml"))


def test_switching_inverter_c_kernel_equals_numba():
    # PWM edges, dead times and piecewise RK4: 1.5 s of the program (the first moves)
    _compare(_switching_axis(), seconds=1.5)


def test_held_inputs_in_chunks_equal_one_run():
    axis = load_axis_config(ROOT / "config" / "emps.yaml")
    kernel = c_kernel_for_axis(axis)
    library = compile_kernel(kernel)
    ref = program_ref(SAMPLE, axis.engine.base_period_s)[:2000]
    one, chunked = CModel(library, kernel), CModel(library, kernel)
    whole = one.run(len(ref), ref=ref)
    parts = [chunked.run(500, ref=ref[i : i + 500]) for i in range(0, len(ref), 500)]
    assert np.array_equal(whole, np.concatenate(parts))


def _translate(text: str):
    tr = Translator()
    return tr.function(Source(text, "f", {}), (DOUBLE, ArrayKind()))


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            "    return [x]\n",
            r"^feed_twin.native.generated.f \(<generated>:2\): the expression List does not "
            r"translate to C$",
        ),
        ("    y = 'a'\n    return x\n", r"the constant 'a' does not translate to C"),
        ("    return a[1:2]\n", r"slices do not translate to C"),
        ("    return math_sin(x)\n", r"the name math_sin is not defined"),
        ("    return max(x, key=x)\n", r"keyword arguments do not translate to C"),
        ("    y = (x, x)\n    y = x\n    return y\n", r"y is bound to a tuple of 2 and a double"),
        ("    with x:\n        pass\n", r"the statement With does not translate to C"),
    ],
)
def test_translator_refuses_what_it_cannot_translate_with_the_place(body, message):
    with pytest.raises(TranslationError, match=message):
        _translate(f"def f(x, a):\n{body}")


def _recursive(x):
    return _recursive(x - 1.0)


def test_translator_refuses_recursion():
    with pytest.raises(
        TranslationError,
        match=r"_recursive \(.*test_native_kernel.py:\d+\): a "
        r"recursive call does not translate to C$",
    ):
        Translator().function(_recursive, (DOUBLE,))


def test_integer_modulo_is_pythons_floor_modulo_also_by_a_power_of_two(tmp_path):
    # a literal power-of-two divisor compiles to a mask (the delay ring's index): the same values
    tr = Translator()
    divisors = (16, 6, -8, 1)
    names = [
        tr.function(Source(f"def f(a):\n    return a % {d}\n", "f", {}), (INT,))[0]
        for d in divisors
    ]
    wrappers = "".join(
        f"int64_t mod_{i}(int64_t a) {{ return {name}(a); }}\n" for i, name in enumerate(names)
    )
    c_path = tmp_path / "mod.c"
    c_path.write_text(
        "#include <math.h>\n#include <stdint.h>\n" + PRELUDE + tr.source() + "\n" + wrappers
    )
    library = tmp_path / "mod.so"
    run_cc(find_cc(), [*FLAGS, "-shared"], [c_path], library)
    lib = ctypes.CDLL(str(library))
    values = [-(2**63), -(2**63) + 1, -17, -16, -15, -1, 0, 1, 15, 16, 17, 2**63 - 1]
    values += [int(v) for v in np.random.default_rng(3).integers(-(10**12), 10**12, 200)]
    for i, d in enumerate(divisors):
        fn = getattr(lib, f"mod_{i}")
        fn.restype, fn.argtypes = ctypes.c_int64, [ctypes.c_int64]
        assert [fn(v) for v in values] == [v % d for v in values], d


def test_missing_compiler_is_named_with_its_debian_package():
    with pytest.raises(
        CompilerMissingError,
        match=r"^no C compiler: `no-such-cc` is not on the PATH; "
        r"install the Debian package gcc \(apt-get install gcc\)$",
    ):
        find_cc("no-such-cc")


def test_open_loop_c_kernel_equals_numba():
    # EMPS driven by a prescribed effort (the drive rows), no controller in either kernel
    axis = load_axis_config(ROOT / "config" / "emps.yaml")
    n = 3000
    drive = np.zeros((n, signals.OUT_SIZE))
    drive[:, signals.OUT_ENABLED] = 1.0
    drive[:, signals.OUT_EFFORT_CMD] = 2.0 * np.sin(np.arange(n) * 2e-3)
    engine = build_engine(axis, closed_loop=False, output_period_s=axis.engine.base_period_s)
    expected = engine.run(n, drive=drive)
    kernel = c_kernel_for_axis(axis, closed_loop=False)
    got = CModel(compile_kernel(kernel), kernel).run(n, drive=drive)
    assert kernel.record_names == expected.names
    assert np.array_equal(got, expected.data)
    assert np.ptp(expected["table.s"]) > 1e-3


def test_a_runaway_stops_the_c_kernel_with_the_state_named():
    axis = load_axis_config(ROOT / "config" / "axis_default.yaml")
    kernel = c_kernel_for_axis(axis)
    model = CModel(compile_kernel(kernel), kernel)
    model.set_param("coupling.k", 1e12)  # RK4 at 62.5 us is unstable for this coupling
    with pytest.raises(RuntimeError, match=r"^state motor.omega ran away at tick \d+ \(value "):
        model.run(100)
    assert 0 < model.tick() < 100
