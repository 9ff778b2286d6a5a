"""The shadow twin of a machine: every axis shadowed beside its stand-in, residuals and health
per axis; a guide that wears on X is reported on X alone."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import yaml

from feed_twin.cli import main as cli_main
from feed_twin.machine.config import load_machine_config
from feed_twin.machine.shadow import shadow_machine

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = "G90 G54 G17\n" + "G1 X-50 Z-50 F6000\nG1 X50 Z50\n" * 3 + "M2\n"


def write_worn_machine(directory: Path) -> None:
    """machine.yaml (X's guide friction doubling at 2 s in its stand-in) and p.ngc in
    `directory`."""
    machine = yaml.safe_load((ROOT / "config" / "machine_default.yaml").read_text())
    axis = (ROOT / "config" / "axis_default.yaml").read_text()
    shadow = yaml.safe_load(axis)["shadow"]
    shadow["standin"]["friction_steps"] = [{"at_s": 2.0, "scale": 2.0}]
    # a warning identifies the effect at every evaluation (seconds each): every 0.5 s here
    shadow["evaluate_period_s"] = 0.5
    machine["axes"]["X"]["shadow"] = shadow
    (directory / "axis_default.yaml").write_text(axis)
    (directory / "machine.yaml").write_text(yaml.safe_dump(machine))
    (directory / "p.ngc").write_text(PROGRAM)


def test_a_worn_x_guide_warns_on_x_only(tmp_path, capsys):
    write_worn_machine(tmp_path)
    argv = ["run", str(tmp_path / "p.ngc"), "--config", str(tmp_path / "machine.yaml")]
    argv += ["--out", str(tmp_path), "--name", "m", "--shadow", "--in-process", "--json"]
    assert cli_main(argv) == 0
    out = capsys.readouterr().out
    record = json.loads(out.strip().splitlines()[-1])["shadow"]
    assert set(record) == {"x", "y", "z"}
    # the truth's guide friction doubles at 2 s (+120 N, 0.1 A while moving): X warns after it
    assert record["x"]["health"] == "WARN"
    assert 2.0 < record["x"]["first_warning_s"] < 3.5
    # which effect the health names while its window straddles the step varies (friction,
    # asymmetric friction, torque constant: README): one is named
    assert record["x"]["effect"] and record["x"]["message"]
    # Y stands still, Z moves as before: the stand-in differs from the model only by its
    # unmodelled dynamics and noise (config/axis_default.yaml: effort deviation about 0.05 A)
    for axis in ("y", "z"):
        assert record[axis]["health"] == "OK", record[axis]
        assert record[axis]["effort_dev_rms"] < 0.06
    assert record["z"]["fe_dev_rms_m"] < 2e-6
    assert "shadow x: FE deviation RMS" in out


def test_the_worn_guide_is_estimated_near_its_true_change(tmp_path):
    """Once the health window holds only worn motion, the estimate is the truth's step: the guide
    friction doubles (+100 %). The baseline residual model must stay well-posed on a one-way
    cruise (|v| and v, or a standstill indicator, nearly collinear there): fitted all at once,
    it once predicted 1000 A and named a Coulomb change of -336063 %."""
    write_worn_machine(tmp_path)
    x = shadow_machine(load_machine_config(tmp_path / "machine.yaml"), tmp_path / "p.ngc")["X"]
    named = [v for v in x.verdicts if math.isfinite(v.relative_change)]
    assert named, [v.message for v in x.verdicts]
    # the last window holds worn motion only: the guide's friction, doubled (its Coulomb part
    # +100 %, or its Stribeck part, which doubled with it)
    last = x.verdicts[-1]
    assert last.effect in ("coulomb_friction", "stribeck_friction"), last.message
    # X runs at one speed both ways (F6000 on the 45-degree X-Z line: 70.7 mm/s), where a
    # Coulomb and a viscous change have the same signature (sign v and v): a window may name
    # either, and the name holds while later windows cannot tell them apart (health.py). What
    # is determined is the force added at that speed, the truth's +120 N. Measured: after the
    # jerk filter's integral became two doubles (the command moved by rounding) the first
    # windows named viscous_friction +394 % and +423 % (111 and 120 N at 70.7 mm/s) where they
    # had named the Coulomb change; from 4.5 s on coulomb_friction +98-101 %.
    v_x = 0.1 / math.sqrt(2.0)
    for v in named:
        if v.effect == "viscous_friction":
            added = (v.estimated_value - v.nominal_value) * v_x
            assert added == pytest.approx(120.0, rel=0.15), v.message
        else:
            assert v.relative_change == pytest.approx(1.0, abs=0.15), v.message
    # no window reports a size it cannot determine (opposite weights of |v| and "moving" on a
    # cruise, a Stribeck speed the window never reaches): what an effect adds stays near the
    # truth's change (120 N, about 0.1 A)
    for v in x.verdicts:
        added = re.search(r"adds up to (\S+) A", v.message)
        assert added is None or float(added.group(1)) < 0.5, v.message
