"""The message-fault policy of one machine stream (feed_twin.shadow.stream) and the shadow config.

A stream of position samples x_k = 1e-3 * k m (1 kHz) makes every fill checkable exactly:
linear interpolation of a straight line gives back the line.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest

from feed_twin.core.config import ConfigError
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.stream import MAX_JUMP_S, SlotStream

T = 1e-3


def stream(fill: Literal["hold", "interpolate"] = "interpolate", window: int = 3) -> SlotStream:
    s = SlotStream(name="measured", width=1, period_s=T, tolerance=0.25, window=window, fill=fill)
    s.set_origin(0.0)
    s.start(0)
    return s


def feed(s: SlotStream, slots: list[int]) -> list[str]:
    return [s.push(k * T, (1e-3 * k,)) for k in slots]


def released(s: SlotStream, *, final: bool = False):
    r = s.release(final=final)
    assert r is not None
    return np.arange(r.first, r.first + len(r.values)), r.values[:, 0], r.filled


def test_in_order_stream_is_released_once_the_window_has_passed() -> None:
    s = stream(window=3)
    assert feed(s, [0, 1, 2, 3, 4]) == ["accepted"] * 5
    slots, x, filled = released(s)
    # real samples are released at once; only gaps wait for the window
    np.testing.assert_array_equal(slots, [0, 1, 2, 3, 4])
    np.testing.assert_allclose(x, 1e-3 * slots, rtol=0, atol=1e-15)
    assert not filled.any()
    assert s.release() is None
    assert s.counts.accepted == 5 and s.counts.missing == 0


def test_missing_sample_is_interpolated_after_the_window_and_counted() -> None:
    s = stream(window=3)
    feed(s, [0, 1, 3, 4])
    slots, x, _ = released(s)
    np.testing.assert_array_equal(slots, [0, 1])  # slot 2 is not decided until slot 5 arrives
    feed(s, [5])
    slots, x, filled = released(s)
    np.testing.assert_array_equal(slots, [2, 3, 4, 5])
    np.testing.assert_allclose(x, 1e-3 * slots, rtol=0, atol=1e-15)  # a line interpolates exactly
    np.testing.assert_array_equal(filled, [True, False, False, False])
    assert s.counts.missing == 1 and s.counts.missing_run == 0


def test_missing_sample_is_held_with_the_hold_policy() -> None:
    s = stream(fill="hold", window=2)
    feed(s, [0, 1, 3, 4])
    slots, x, filled = released(s)
    np.testing.assert_array_equal(slots, [0, 1, 2, 3, 4])
    assert x[2] == pytest.approx(1e-3 * 1)  # the value of slot 1, held
    np.testing.assert_array_equal(filled, [False, False, True, False, False])


def test_a_run_of_missing_samples_is_counted_until_a_real_one_arrives() -> None:
    s = stream(window=2)
    feed(s, [0])
    released(s)
    for k in range(3, 9):
        feed(s, [k])
    # slots 1 and 2 are filled; then real samples reset the run
    released(s)
    assert s.counts.missing == 2 and s.counts.missing_run == 0
    s2 = stream(window=2)
    feed(s2, [0, 10])
    released(s2)
    assert s2.counts.missing_run == 8  # slots 1..8 are decided (10 - window), 9 is not yet
    released(s2, final=True)
    assert s2.counts.missing == 9 and s2.counts.missing_run == 0


def test_late_sample_after_its_slot_was_decided_is_dropped_and_counted() -> None:
    s = stream(window=2)
    feed(s, [0, 1, 3, 4])  # slot 2 is decided when slot 4 arrives
    assert feed(s, [2]) == ["late"]
    slots, x, filled = released(s)
    np.testing.assert_array_equal(filled, [False, False, True, False, False])
    assert s.counts.late == 1
    # the decision does not depend on when release() is called
    s2 = stream(window=2)
    feed(s2, [0, 1, 3, 4, 2])
    _, x2, filled2 = released(s2)
    np.testing.assert_array_equal(filled2, filled)
    np.testing.assert_array_equal(x2, x)


def test_out_of_order_sample_within_the_window_is_put_in_its_place() -> None:
    s = stream(window=3)
    assert feed(s, [0, 2, 1, 3]) == ["accepted", "accepted", "reordered", "accepted"]
    slots, x, filled = released(s)
    np.testing.assert_array_equal(slots, [0, 1, 2, 3])
    np.testing.assert_allclose(x, 1e-3 * slots, rtol=0, atol=1e-15)
    assert not filled.any() and s.counts.reordered == 1


def test_duplicates_are_dropped_buffered_or_released() -> None:
    s = stream(window=3)
    assert feed(s, [0, 1, 1]) == ["accepted", "accepted", "duplicated"]
    released(s)
    assert feed(s, [1]) == ["duplicated"]
    assert s.counts.duplicated == 2 and s.counts.accepted == 2


def test_stamp_off_the_grid_is_dropped_and_counted() -> None:
    s = stream()
    assert s.push(0.4 * T, (0.0,)) == "off_grid"
    assert s.push(1.2 * T, (1e-3,)) == "accepted"  # 0.2 periods off: within the tolerance
    assert s.counts.off_grid == 1


def test_a_corrupt_stamp_far_ahead_is_rejected_not_simulated() -> None:
    s = stream()
    feed(s, [0])
    assert s.push(2 * MAX_JUMP_S, (1.0,)) == "rejected"
    assert s.newest == 0 and s.counts.rejected == 1


def test_samples_before_the_start_are_late() -> None:
    s = SlotStream(name="m", width=1, period_s=T, tolerance=0.25, window=3, fill="hold")
    s.set_origin(0.0)
    feed(s, [0, 1, 2])
    s.start(1)
    assert s.counts.late == 1 and s.counts.accepted == 2
    slots, _, _ = released(s)
    np.testing.assert_array_equal(slots, [1, 2])


def test_push_many_decides_exactly_as_single_pushes() -> None:
    rng = np.random.default_rng(3)
    order = np.arange(2000)
    order = order[rng.random(2000) > 0.05]  # 5 % lost
    swap = rng.choice(len(order) - 1, 40, replace=False)
    order[swap], order[swap + 1] = order[swap + 1], order[swap].copy()  # neighbours swapped
    order = np.insert(order, rng.choice(len(order), 20), order[rng.choice(len(order), 20)])
    a, b = stream(window=4), stream(window=4)
    for k in order:
        a.push(k * T, (1e-3 * k,))
    for part in np.array_split(order, 17):
        b.push_many(part * T, (1e-3 * part)[:, None])
    ra, rb = a.release(final=True), b.release(final=True)
    assert ra is not None and rb is not None, "both streams started and hold pushed samples"
    np.testing.assert_array_equal(ra.values, rb.values)
    np.testing.assert_array_equal(ra.filled, rb.filled)
    assert a.counts == b.counts
    assert a.counts.missing > 0 and a.counts.duplicated > 0 and a.counts.reordered > 0


def test_memory_stays_bounded_on_a_long_stream() -> None:
    s = stream(window=5)
    for block in range(100):
        k = np.arange(block * 1000, (block + 1) * 1000)
        s.push_many(k * T, (1e-3 * k)[:, None])
        s.release()
        assert s.pending_count <= 5 + 1
        assert len(s._released_real) <= 4 * 5 + 16


def test_release_before_start_or_without_samples_is_none() -> None:
    s = SlotStream(name="m", width=1, period_s=T, tolerance=0.25, window=3, fill="hold")
    assert s.release() is None
    with pytest.raises(RuntimeError, match="m: the slot grid has no origin yet"):
        s.push(0.0, (0.0,))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"period_s": 0.0}, r"x: period_s = 0.0: must be > 0"),
        ({"window": 0}, r"x: window = 0: must be >= 1"),
        ({"fill": "zero"}, r"x: fill = 'zero': must be 'hold' or 'interpolate'"),
    ],
)
def test_stream_parameters_are_checked(kwargs: dict, message: str) -> None:
    args = {"name": "x", "width": 1, "period_s": T, "tolerance": 0.25, "window": 3, "fill": "hold"}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        SlotStream(**args)


SHADOW = {
    "sample_period_s": 1.0e-3,
    "stamp_tolerance": 0.25,
    "reorder_window": 5,
    "missing_fill": "interpolate",
    "missing_flag_after": 20,
    "window_s": 4.0,
    "baseline_s": 6.0,
    "evaluate_period_s": 1.0,
    "fe_dev_rms_warn_m": 2.0e-6,
    "fe_dev_rms_error_m": 2.0e-5,
    "effort_dev_rms_warn": 1.5,
    "effort_dev_rms_error": 15.0,
}


def test_shadow_config_loads_and_derives_sample_counts() -> None:
    cfg = load_shadow_config({"shadow": SHADOW}, source="s.yaml")
    assert (cfg.window_samples, cfg.baseline_samples, cfg.evaluate_samples) == (4000, 6000, 1000)
    shipped = load_shadow_config("config/emps.yaml")
    assert shipped.sample_period_s == 1e-3


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"stamp_tolerance": 0.6}, r"shadow.stamp_tolerance = 0.6: must lie in \[0.0, 0.5\]"),
        ({"reorder_window": 0}, r"s.yaml: shadow.reorder_window = 0: must be a whole number >= 1"),
        ({"missing_fill": "zero"}, r"s.yaml: shadow.missing_fill = 'zero': must be one of"),
        ({"window_s": 0.005}, r"shadow.window_s = 0.005: must span at least 10 samples"),
        ({"baseline_s": -1.0}, r"s.yaml: shadow.baseline_s = -1.0: must be > 0"),
        (
            {"effort_dev_rms_error": 1.0},
            r"shadow.effort_dev_rms_error = 1.0: must be above effort_dev_rms_warn = 1.5",
        ),
        (
            {"fe_dev_rms_error_m": 1e-6},
            r"shadow.fe_dev_rms_error_m = 1e-06: must be above fe_dev_rms_warn_m = 2e-06",
        ),
        ({"typo": 1}, r"s.yaml: shadow: unknown key\(s\) typo"),
    ],
)
def test_shadow_config_errors_name_file_field_and_value(change: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_shadow_config({"shadow": {**SHADOW, **change}}, source="s.yaml")


def test_shadow_config_needs_its_section(tmp_path) -> None:
    path = tmp_path / "axis.yaml"
    path.write_text("plant: {}\n")
    with pytest.raises(ConfigError, match=r"axis.yaml: missing required section shadow"):
        load_shadow_config(path)


def test_rolling_rms_equals_the_window_rms_for_any_block_sizes() -> None:
    from feed_twin.shadow.twin import _RollingRms

    rng = np.random.default_rng(1)
    values = rng.normal(0.0, 2.0, 5000)
    rolling = _RollingRms(700)
    got, i = [], 0
    for size in rng.choice([1, 1, 1, 3, 100, 900], 400):
        got.append(rolling(values[i : i + size]))
        i += size
        if i >= len(values):
            break
    got = np.concatenate(got)
    want = [np.sqrt(np.mean(values[max(0, k - 699) : k + 1] ** 2)) for k in range(len(got))]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_health_window_ring_keeps_the_last_rows_in_order() -> None:
    from feed_twin.shadow.health import _Ring

    ring = _Ring(10, 1)
    rows = np.arange(37.0)[:, None]
    i = 0
    for size in (3, 1, 12, 4, 9, 8):
        ring.extend(rows[i : i + size])
        i += size
        np.testing.assert_array_equal(ring.data[:, 0], rows[max(0, i - 10) : i, 0])
