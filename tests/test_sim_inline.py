"""Inlined parameters (engine.inline_parameters): the parameter values compiled into the kernel
give the same bits as the kernel that reads them, and cannot be changed behind its back."""

import dataclasses
import math

import numpy as np
import pytest

from feed_twin.control import signals as sig
from feed_twin.io.config import ConfigError
from feed_twin.sim.batch import run_batch
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.kernel import _literal

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
