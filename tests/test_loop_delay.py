"""measurement_delay delays what the loops read, not a scale that only records."""

from __future__ import annotations

from pathlib import Path

from twin_support import strong_candidate

from feed_twin.analysis.effects import BY_NAME
from feed_twin.analysis.model_doc import ModelDoc, model_of

ROOT = Path(__file__).resolve().parents[1]
DELAY = BY_NAME["measurement_delay"]


def _tied(path: Path) -> tuple[str, ...]:
    edit = DELAY.edit(ModelDoc.load(path), strong_candidate("measurement_delay", {}))
    assert [p.name for p in edit.own] == ["sensors.delay_ticks"]
    assert edit.grid == tuple(range(9))
    return model_of(edit.doc).tie_members("sensors.delay_ticks")


def test_a_semi_closed_loop_delays_its_encoder_and_records_the_scale_on_time():
    # config/truth_nominal.yaml: the position loop on the motor encoder, a scale that records
    assert _tied(ROOT / "config" / "truth_nominal.yaml") == ("encoder.delay_ticks",)
    doc = DELAY.truth(ModelDoc.load(ROOT / "config" / "truth_nominal.yaml"), {"delay_ticks": 3})
    assert (doc.get("encoder.delay_ticks"), doc.get("scale.delay_ticks")) == (3, 0)
    # a delay in seconds (the truth machine's, feed_twin.truth) in the twin's ticks (0.25 ms:
    # the drive's velocity-loop period)
    doc = DELAY.truth(ModelDoc.load(ROOT / "config" / "truth_nominal.yaml"), {"delay_s": 2e-3})
    assert doc.base_period() == 2.5e-4
    assert doc.get("encoder.delay_ticks") == 8


def test_a_loop_closed_on_the_scale_delays_both_sensors_it_reads():
    # config/axis_default.yaml: position on the scale, speed on the motor encoder
    assert set(_tied(ROOT / "config" / "axis_default.yaml")) == {
        "encoder.delay_ticks",
        "scale.delay_ticks",
    }
