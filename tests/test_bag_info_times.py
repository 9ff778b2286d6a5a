"""`bag info` gives its start and end as dates a person reads, not raw epoch seconds."""

from __future__ import annotations

from feed_twin.io.bag.layout import _utc


def test_a_wall_clock_receive_time_is_a_utc_date_with_its_epoch_seconds() -> None:
    assert _utc(1_764_324_205_123_456_789) == (
        "2025-11-28 10:03:25.123456 UTC (1764324205.123 s since 1970)"
    )


def test_a_simulated_clock_is_said_to_be_one() -> None:
    assert _utc(7_394_000_000) == "7.394000 s (simulated clock, not a date)"
