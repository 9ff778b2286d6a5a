"""Re-examining effects that share a friction's forward/backward pair.

Coulomb friction ties F_c_pos and F_c_neg into one value; asymmetric friction found later splits
the tie. A stiction added after both takes over the Coulomb part, and the joint re-fit moves
what is left to near zero: the Coulomb effect is then read through the split tie's members, and
the asymmetry as each member's distance from the pair's mean (not from the values the pair had
before the asymmetry was found, which a later effect moved).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.reexamine import Found, collapsed, removed, split_pairs
from feed_twin.analysis.report import FoundEffect

ROOT = Path(__file__).resolve().parents[1]
FC, FC_POS, FC_NEG = "friction.F_c", "friction.F_c_pos", "friction.F_c_neg"
FV, FV_POS, FV_NEG = "friction.F_v", "friction.F_v_pos", "friction.F_v_neg"


def _found(name: str, neutral, at_discovery, pairs=(), members=None) -> Found:
    return Found(
        effect=FoundEffect(
            name=name, evidence="", parameters={}, explained_fraction=0.0, component="friction"
        ),
        own=(),
        neutral=neutral,
        at_discovery=at_discovery,
        report={},
        added=1,
        pairs=pairs,
        members=members or {},
    )


def _friction(doc: ModelDoc, c_pos: float, c_neg: float, v_pos: float, v_neg: float):
    for slot, value in ((FC_POS, c_pos), (FC_NEG, c_neg), (FV_POS, v_pos), (FV_NEG, v_neg)):
        doc = doc.set(slot, value)
    return doc


@pytest.fixture(scope="module")
def nominal() -> ModelDoc:
    return ModelDoc.load(ROOT / "config" / "emps_nominal.yaml")


def test_the_pairs_an_effect_splits_and_the_ties_it_owns(nominal):
    tied = nominal.tie(FC, (FC_POS, FC_NEG)).tie(FV, (FV_POS, FV_NEG))
    pairs, members = split_pairs(tied, tied.untie(), (FV_POS, FV_NEG, FC_POS, FC_NEG))
    assert set(pairs) == {(FC_POS, FC_NEG), (FV_POS, FV_NEG)}
    assert members == {}
    # the Coulomb effect's own slot is the tie: its members are kept with it
    pairs, members = split_pairs(nominal, tied, (FC,))
    assert pairs == () and members == {FC: (FC_POS, FC_NEG)}
    # a pair only partly among the slots is not split by the effect
    assert split_pairs(tied, tied.untie(), (FV_POS,))[0] == ()


def test_an_asymmetry_is_measured_from_the_pairs_mean(nominal):
    # found at 16.6 / 20.4 N and 175.6 / 212.8 N s/m, when the Coulomb force was 16.0 N
    asym = _found(
        "asymmetric_friction",
        neutral={FC_POS: 16.0, FC_NEG: 16.0, FV_POS: 203.5, FV_NEG: 203.5},
        at_discovery={FC_POS: 16.6, FC_NEG: 20.4, FV_POS: 175.6, FV_NEG: 212.8},
        pairs=((FC_POS, FC_NEG), (FV_POS, FV_NEG)),
    )
    doc = nominal.untie()
    # a stiction took the Coulomb part over: both far from 16 N, but as asymmetric as found
    assert not collapsed(asym, _friction(doc, 0.6, 4.4, 175.6, 212.8))
    # 0.44 N of the 1.9 N asymmetry left (23 % > COLLAPSE): still there
    assert not collapsed(asym, _friction(doc, 0.24, 1.11, 200.5, 199.7))
    # every member within a tenth of its distance from the mean at discovery
    assert collapsed(asym, _friction(doc, 0.55, 0.65, 200.6, 199.9))
    # removing it ties each pair again at its mean
    gone = removed(asym, _friction(doc, 0.24, 1.11, 200.5, 199.7))
    assert gone.get(FC_POS) == gone.get(FC_NEG) == pytest.approx(0.675)
    assert gone.get(FV_POS) == gone.get(FV_NEG) == pytest.approx(200.1)


def test_a_coulomb_force_whose_tie_was_split_is_read_through_its_members(nominal):
    coulomb = _found(
        "coulomb_friction",
        neutral={FC: 0.0},
        at_discovery={FC: 16.0},
        members={FC: (FC_POS, FC_NEG)},
    )
    split = nominal.untie()
    assert not split.has_slot(FC)
    assert not collapsed(coulomb, _friction(split, 15.0, 17.0, 203.5, 203.5))
    # mean 0.675 N: 4 % of the 16 N at discovery
    assert collapsed(coulomb, _friction(split, 0.24, 1.11, 203.5, 203.5))
    gone = removed(coulomb, _friction(split, 0.24, 1.11, 203.5, 203.5))
    assert gone.get(FC_POS) == gone.get(FC_NEG) == 0.0
    # an effect with no readable slot has nothing that could have collapsed
    lost = _found("coulomb_friction", neutral={FC: 0.0}, at_discovery={FC: 16.0})
    assert not collapsed(lost, split)
