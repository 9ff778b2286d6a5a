"""What the engine's speed-ups must not change: noise drawn in blocks, parameters as a tuple."""

import numpy as np

from feed_twin.control import signals as sig
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.kernel import NOISE_BLOCK


def test_noisy_axis_in_chunks_across_noise_blocks_is_bit_identical_to_one_run():
    axis = load_axis_config("config/axis_default.yaml")
    h = axis.engine.base_period_s
    sizes = (1, NOISE_BLOCK - 2, NOISE_BLOCK + 1, 2 * NOISE_BLOCK, 71)
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
