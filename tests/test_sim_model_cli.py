"""`feed-twin model`: coordinates and natural frequencies of an axis config."""

from __future__ import annotations

import re

from feed_twin.cli import main


def test_model_lists_coordinates_and_the_axial_mode_falling_with_position(capsys):
    assert main(["model", "--config", "config/axis_default.yaml", "--positions", "0.0", "0.8"]) == 0
    text = capsys.readouterr().out
    assert "config/axis_default.yaml: 17 components, 12 states" in text
    assert re.search(r"coordinate table +200 kg +backlash.b, cutting.flange", text)
    assert re.search(r"coordinate motor +0.0032 kg m\^2", text)
    first = [float(m) for m in re.findall(r"modes at \+0\.[08]00 m: ([0-9.]+) Hz", text)]
    # fixed-free screw: the first axial mode drops as the nut moves away from the fixed bearing
    assert len(first) == 2 and 150.0 < first[0] < 180.0 and 110.0 < first[1] < 135.0


def test_model_of_a_rigid_body_has_no_modes(capsys):
    assert main(["model", "--config", "config/emps.yaml"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"coordinate table +95.11 kg", text)
    assert "modes at +0.000 m: \n" in text
