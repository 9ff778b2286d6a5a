"""Figures rounded to their meaning; no percentage of a near-zero base."""

from __future__ import annotations

from feed_twin.analysis import wording
from feed_twin.analysis.significance import Verdict


def test_a_residual_made_worse_is_a_ratio_not_a_negative_percentage():
    assert wording.share(-94.673, "effort") == "makes the effort residual energy 95.7x larger"
    assert wording.share(0.21134, "effort") == "removes 21.1 % of the effort residual energy"
    assert wording.share(1e-5, "position") == "leaves the position residual unchanged"


def test_verdict_words_use_them():
    v = Verdict(
        likelihood_ratio=12.345,
        p_value=0.0123,
        explained={"effort": -95.673, "position": 0.999},
        significant=False,
        own="position",
    )
    assert v.words() == (
        "makes the effort residual energy 96.7x larger; removes 99.9 % of the position "
        "residual energy (LR = 12.3, p = 0.012)"
    )
    assert "%" not in wording.share(-95.673, "effort")


def test_values_and_percentages_to_their_meaning():
    assert wording.values({"F_hold_N": 4686.361797091936, "v_s": 0.00123456}) == (
        "F_hold_N = 4686, v_s = 0.001235"
    )
    assert wording.percent(100.01863253320722) == "100 %"
    assert wording.percent(51.145879234958215) == "51.1 %"
    assert wording.percent(None) == "-"
