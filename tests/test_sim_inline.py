"""Parameter values compiled into the kernel.

- Inlined parameters (engine.inline_parameters): every value compiled in gives the same bits as
  the kernel that reads them, and cannot be changed behind its back.
- The controller's structure (layout.STRUCTURE_SLOTS), compiled into the default kernel: the
  same bits as the kernel that reads every slot; a structure changed in `cp` (assigned or in
  place) runs on its own kernel; a batch whose sets differ in structure runs each on the right
  one.
"""

import dataclasses
import math

import numpy as np
import pytest

from feed_twin.control import layout as lay
from feed_twin.core import signals as sig
from feed_twin.core.config import ConfigError
from feed_twin.sim.batch import run_batch
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.kernel import _literal, kernel_source, load_kernel

AXIS = "config/axis_default.yaml"


def _ramp(n: int, h: float) -> np.ndarray:
    ref = np.zeros((n, sig.REF_SIZE))
    v = np.minimum(np.arange(n) * h * 2.0, 0.1)  # 2 m/s^2 up to 0.1 m/s
    ref[:, sig.REF_VEL_M_S] = v
    ref[:, sig.REF_POS_M] = np.cumsum(v) * h
    return ref


@pytest.fixture(scope="module")
def engines():
    axis = load_axis_config(AXIS)
    inlined = dataclasses.replace(
        axis, engine=dataclasses.replace(axis.engine, inline_parameters=True)
    )
    return build_engine(axis), build_engine(inlined)


def test_inlined_parameters_give_the_bits_of_the_kernel_that_reads_them(engines):
    tunable, inlined = engines
    assert inlined.kernel is not tunable.kernel
    n = round(0.1 / tunable.h)
    ref = _ramp(n, tunable.h)
    a = tunable.run(n, ref=ref)
    b = inlined.run(n, ref=ref)
    assert np.array_equal(a.data, b.data)
    assert np.max(np.abs(a["table.v"])) > 0.05  # the axis moved: the controller ran its loops


def test_an_inlined_engine_refuses_new_parameter_values(engines):
    _, inlined = engines
    with pytest.raises(ValueError, match=r"^p: this engine's parameters are compiled into its"):
        inlined.p = inlined.p * 1.1
    with pytest.raises(ValueError, match=r"^cp: .*inline_parameters: true"):
        inlined.cp = inlined.cp.copy()
    with pytest.raises(ValueError, match="read-only"):
        inlined.p[0] = 1.0


def test_a_batch_on_an_inlined_engine_reads_each_sets_parameters(engines):
    tunable, inlined = engines
    n = round(0.02 / tunable.h)
    ref = _ramp(n, tunable.h)
    model = tunable.model
    P = np.tile(tunable.p, (2, 1))
    P[1, model.param_index["table.m"]] *= 1.5
    model.fill_derived(P)
    batch = run_batch(inlined, P, n, ref=ref)
    single = tunable.run(n, ref=ref)
    assert np.array_equal(batch.data[0], single.data)
    assert not np.array_equal(batch.data[1], single.data)  # the heavier table: other bits


def test_inline_parameters_must_be_a_boolean():
    raw = load_axis_config(AXIS).raw
    bad = dict(raw, engine=dict(raw["engine"], inline_parameters="yes"))
    with pytest.raises(ConfigError, match=r"engine\.inline_parameters"):
        load_axis_config(bad, source="axis.yaml")


def test_literals_read_back_to_the_same_bits():
    rng = np.random.default_rng(3)
    values = [*rng.normal(0.0, 1e3, 50), 1e-300, -0.0, 0.1, math.inf, -math.inf, math.nan]
    for v in values:
        back = eval(_literal(v), {"math": math})
        assert np.array(back).tobytes() == np.array(v).tobytes() or (
            math.isnan(v) and math.isnan(back)
        )


def test_parameter_vectors_of_the_wrong_length_are_refused(engines):
    tunable, _ = engines
    n = len(tunable.model.param_names)
    with pytest.raises(ValueError, match=rf"^p: shape \({n - 1},\) given, expected \({n},\)$"):
        tunable.p = tunable.p[:-1]
    with pytest.raises(ValueError, match=r"^cp: shape \(3,\) given, expected"):
        tunable.cp = np.zeros(3)
    axis = load_axis_config(AXIS)
    with pytest.raises(ValueError, match=rf"^params: shape \(2,\) given, expected \({n},\)$"):
        build_engine(axis, params=np.zeros(2))
    open_loop = build_engine(axis, closed_loop=False)
    with pytest.raises(ValueError, match="open loop, it has no controller parameters"):
        open_loop.cp = np.zeros(3)
    tunable.p = tunable.p.copy()  # the right length is taken


@pytest.fixture(scope="module")
def axis():
    return load_axis_config(AXIS)


@pytest.fixture(scope="module")
def without_delay(axis):
    """The same axis with the computation delay off: another controller structure."""
    controller = dataclasses.replace(axis.controller, computation_delay=False)
    return build_engine(dataclasses.replace(axis, controller=controller))


def test_the_structure_is_compiled_in_and_nothing_else(axis):
    engine = build_engine(axis)
    text = kernel_source(
        engine.model,
        closed_loop=True,
        cp_slots=[float(v) if i in lay.STRUCTURE_SLOTS else None for i, v in enumerate(engine.cp)],
    )
    cpt = next(line for line in text.splitlines() if line.strip().startswith("cpt = "))
    read = [i for i in range(engine.cp.size) if f"cp[{i}]" in cpt]
    assert read == [i for i in range(engine.cp.size) if i not in lay.STRUCTURE_SLOTS]
    pt = next(line for line in text.splitlines() if line.strip().startswith("pt = "))
    assert pt.count("p[") == len(engine.model.param_names)  # the plant's values are all read


def test_the_structured_kernel_gives_the_bits_of_the_kernel_that_reads_every_slot(axis):
    engine = build_engine(axis)
    n = round(0.05 / engine.h)
    ref = _ramp(n, engine.h)
    a = engine.run(n, ref=ref)
    engine.kernel_for(engine.cp)  # the structured kernel, compiled
    generic = load_kernel(engine.model, closed_loop=True)  # reads every slot of p and cp
    assert generic is not engine.kernel
    engine._kernels[tuple(engine.cp[list(lay.STRUCTURE_SLOTS)].tolist())] = generic
    b = engine.run(n, ref=ref)
    assert np.array_equal(a.data, b.data)
    assert np.max(np.abs(a["table.v"])) > 0.05  # the axis moved: every loop ran


def test_a_structure_changed_in_cp_runs_on_its_own_kernel(axis, without_delay):
    n = round(0.02 / without_delay.h)
    ref = _ramp(n, without_delay.h)
    expected = without_delay.run(n, ref=ref)
    slot = lay.P_COMPUTATION_DELAY
    assigned = build_engine(axis)
    delayed = assigned.run(n, ref=ref)
    kernel = assigned.kernel
    cp = assigned.cp.copy()
    cp[slot] = without_delay.cp[slot]
    assert np.array_equal(cp, without_delay.cp)
    assigned.cp = cp
    assert assigned.kernel is not kernel
    assert np.array_equal(assigned.run(n, ref=ref).data, expected.data)
    assert not np.array_equal(delayed.data, expected.data)  # the delay shows in the signals

    in_place = build_engine(axis)
    in_place.cp[slot] = without_delay.cp[slot]  # behind the engine's back
    assert np.array_equal(in_place.run(n, ref=ref).data, expected.data)


def test_a_batch_runs_each_set_on_the_kernel_of_its_structure(axis, without_delay):
    engine = build_engine(axis, record=["table.s", "out.duty_a"])
    n = round(0.02 / engine.h)
    ref = _ramp(n, engine.h)
    CP = np.array([engine.cp, without_delay.cp, engine.cp])
    P = np.tile(engine.p, (3, 1))
    res = run_batch(engine, P, n, ref=ref, controller_params=CP, threads=2)
    assert not res.diverged.any()
    for b, cp in enumerate(CP):
        engine.cp = cp
        single = engine.run(n, ref=ref)
        assert np.array_equal(res.data[b], single.data)
    assert not np.array_equal(res.data[0], res.data[1])
