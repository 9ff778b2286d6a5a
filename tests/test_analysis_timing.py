"""A record delay within one twin tick is the twin's own timing (feed_twin.analysis.timing):
kept in the model, said as its alignment, not named; beyond a tick it is the record's."""

from __future__ import annotations

from pathlib import Path

import pytest

import feed_twin
from feed_twin.analysis.report import FoundEffect
from feed_twin.analysis.timing import split_timing, timing_line, within_tick

TICK_S = 1e-3


def _found(name: str, **parameters: float) -> FoundEffect:
    return FoundEffect(
        name=name, evidence="", parameters=parameters, explained_fraction=0.5, component=""
    )


def test_a_delay_within_one_tick_is_timing_beyond_it_a_finding() -> None:
    one_tick = _found("channel_delay", delay_s=TICK_S)  # the drive samples one tick later
    fraction = _found("position_delay", delay_s=-0.125e-3)  # a faster drive's loops
    recorder = _found("channel_delay", delay_s=3e-3)  # a trace recorder's lag
    friction = _found("coulomb_friction", F_c_N=150.0)
    window = _found("trace_window", window_s=0.5e-3)  # no delay: the trace's averaging
    named, timing = split_timing([one_tick, fraction, recorder, friction, window], TICK_S)
    assert timing == [one_tick, fraction]
    assert named == [recorder, friction, window]
    assert not within_tick(_found("channel_delay", delay_s=1.01e-3), TICK_S)


def test_a_sensor_delay_below_one_whole_tick_is_timing_a_whole_tick_a_finding() -> None:
    # a fraction of a tick (the refinement between ticks) is where within it the drive samples
    fraction = _found("measurement_delay", delay_ticks=0.2, delay_s=0.2e-3)
    one_tick = _found("measurement_delay", delay_ticks=1.0, delay_s=TICK_S)
    late = _found("measurement_delay", delay_ticks=4.45, delay_s=4.45e-3)
    named, timing = split_timing([fraction, one_tick, late], TICK_S)
    assert (named, timing) == ([one_tick, late], [fraction])
    line = timing_line(fraction, TICK_S)
    assert "measurement_delay +0.2 ms, within one 1 ms tick" in line


def test_the_timing_line_says_the_delay_and_the_tick() -> None:
    line = timing_line(_found("command_delay", delay_s=-0.125e-3), TICK_S)
    assert "command_delay -0.125 ms, within one 1 ms tick" in line
    assert "not named as a missing effect" in line


def test_a_tick_must_be_positive() -> None:
    with pytest.raises(ValueError, match=r"base_period_s = 0.0: must be > 0"):
        within_tick(_found("channel_delay", delay_s=0.0), 0.0)


@pytest.mark.slow
def test_a_clean_truth_record_names_nothing(tmp_path: Path) -> None:
    """The independent truth machine with nothing hidden, with a seed the benchmarks do not
    use: no effect named. The nominal twin runs its loops at the drive's rates, with its fine
    interpolation and feed-forward (config/truth_nominal.yaml): its following error is within
    1 um RMS of the machine's (4.6 um with every loop at 1 kHz, and a 2 % heavier table was
    named), and no delay within a tick is needed to say its timing."""
    from feed_twin.analysis.diagnose import diagnose
    from feed_twin.analysis.model_doc import ModelDoc
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import make_record

    rec = make_record(tmp_path / "run.csv", hidden={}, seed=7)
    nominal = ModelDoc.load(
        Path(feed_twin.__file__).resolve().parent.parent / "config/truth_nominal.yaml"
    )
    d = diagnose(load_measured(rec.csv, rec.map), nominal)[0]
    assert [e.name for e in d.effects] == [], d.verdict
    assert d.before.fe_dev_rms_m < 1e-6
    assert not [n for n in d.notes if n.startswith("the twin's timing against the machine")]
    assert not d.verdict.startswith("the nominal model misses")
