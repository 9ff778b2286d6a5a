"""The run's end as the sim and the controller both keep it (feed_twin.nodeset.run_end)."""

from __future__ import annotations

import pytest

from feed_twin.nodeset.guard import parse_program_state
from feed_twin.nodeset.run_end import RunEnd

MS = 1_000_000


def _parsed(text: str) -> tuple[str, int | None, str]:
    state = parse_program_state(text)
    assert state is not None, f"{text!r}: not a program state"
    return state


def test_the_end_is_settle_after_the_finish_stamp_and_the_exchange_at_the_end_still_runs():
    end = RunEnd(200 * MS)
    assert not end.passed(10**15)  # unknown: nothing is past it
    word, stamp, _ = _parsed("finished 1000000000")
    assert end.learn(word, stamp)
    assert end.end_ns == 1_200 * MS and end.word == "finished"
    assert not end.passed(1_200 * MS)
    assert end.passed(1_201 * MS)


def test_a_state_without_a_stamp_sets_nothing_and_the_first_end_stands():
    end = RunEnd(0)
    for text in ("running", "paused line 3 (M0)", "error line 2: bad"):
        word, stamp, _ = _parsed(text)
        assert not end.learn(word, stamp)
    assert end.end_ns is None
    assert end.learn("stopped", 5 * MS)
    assert not end.learn("finished", 9 * MS)  # the latched topic repeats, a stop came first
    assert (end.end_ns, end.word) == (5 * MS, "stopped")


def test_controller_and_sim_agree_whatever_order_they_hear_the_end_in():
    """The controller answers exchanges up to the end; a sim that learns the end late has
    waited at the first exchange past it, and ends there: the same exchange either way."""
    period, finish, settle = MS, 40 * MS, 5 * MS
    controller = RunEnd(settle)
    controller.learn("finished", finish)
    answered = [t for t in range(0, 100 * MS, period) if not controller.passed(t)]
    for sim_learns_at in (0, answered[-1], answered[-1] + period):
        sim = RunEnd(settle)
        t = 0
        while True:
            if t == sim_learns_at:
                sim.learn("finished", finish)
            if sim.passed(t) or t not in answered:
                break  # ends now, or waits without a command until it learns the end
            t += period
        sim.learn("finished", finish)
        assert sim.passed(t) and t == answered[-1] + period


def test_a_negative_settle_is_refused():
    with pytest.raises(ValueError, match="settle = -1 ns"):
        RunEnd(-1)
