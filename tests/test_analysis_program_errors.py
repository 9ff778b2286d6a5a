"""`--program` on inputs that cannot be planned or placed as given: one line saying what to do."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.analysis.program import command_from_program
from feed_twin.analysis.synthetic import NC_CONFIG, PROGRAM, write_with_nc
from feed_twin.analysis.twin import ModelDoc
from feed_twin.cli import main
from feed_twin.gcode.config import nc_config_from_mapping
from feed_twin.gcode.planner import plan_program
from feed_twin.io.measured import MeasuredDataError, load_measured, segment

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"  # a plant and its controller, no nc: section

MAP = """\
time: {column: t, unit: s}
position_sensor: motor_encoder
signals:
  pos_meas_m: {column: x, unit: m}
plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}
"""


def _three_times() -> str:
    lines = PROGRAM.splitlines()
    moves = [ln for ln in lines[2:] if ln and ln != "M30"]
    return "\n".join(lines[:2] + moves + ["G4 P0.3"] + moves + ["G4 P0.5"] + moves + ["M30", ""])


def _scope(tmp_path: Path, program: str) -> tuple[Path, Path]:
    """A position-only trace of the program as planned (the axis follows its command exactly:
    the placement alone is under test, not the loop)."""
    nc = nc_config_from_mapping(yaml.safe_load(NC_CONFIG)["nc"], source="<nc>")
    traj = plan_program(program, nc)
    x = traj.axis(nc.twin_axis)[0][::2]
    t = traj.t_s[::2] - traj.t_s[0]
    csv = tmp_path / "scope.csv"
    csv.write_text(
        "t,x\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(t, x, strict=True))
    )
    map_path = tmp_path / "scope_map.yaml"
    map_path.write_text(MAP)
    return csv, map_path


def test_program_with_a_model_without_nc_is_one_line(tmp_path, capsys):
    """No NC of another machine is borrowed in silence: its start position and work offsets
    placed a program 400 mm off and its blocks with false waits."""
    csv, map_path = _scope(tmp_path, PROGRAM)
    program = tmp_path / "part.ngc"
    program.write_text(PROGRAM)
    for command in (
        ["simulate", "--config", str(NOMINAL), "--measured", str(csv), "--out", "t.csv"],
        ["diagnose", str(csv), "--config", str(NOMINAL), "--out", str(tmp_path / "out")],
    ):
        code = main([*command, "--map", str(map_path), "--program", str(program)])
        err = capsys.readouterr().err
        assert code == 2
        assert f"{NOMINAL}: --program needs the model's nc: section" in err
        assert "config/axis_default.yaml" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_a_program_the_record_holds_three_times_points_to_repetitions(tmp_path):
    csv, map_path = _scope(tmp_path, _three_times())
    run = load_measured(csv, map_path)
    program = tmp_path / "part.ngc"
    program.write_text(PROGRAM)
    nc = yaml.safe_load(NC_CONFIG)["nc"]
    with pytest.raises(MeasuredDataError) as err:
        command_from_program(run, program, nc=nc)
    message = str(err.value)
    # one run correlates with the first of three (0.58): placed, the twin stood still in the
    # other two without a word
    assert "scope.csv: the program" in message
    assert "moves the axis for 7.58 s, the record moves for 22.7 s" in message
    assert "add --repetitions or cut one run with --segment t0:t1" in message
    # the hint is right: the first run cut with a segment is placed where it starts
    nc_cfg = nc_config_from_mapping(nc, source="<nc>")
    once_s = float(np.ptp(plan_program(PROGRAM, nc_cfg).t_s))
    placed = command_from_program(segment(run, 0.0, once_s + 0.1), program, nc=nc)
    (note,) = placed.warnings
    shift = re.search(r"the program starts ([-+][0-9.]+) s after the record", note)
    assert shift is not None and abs(float(shift.group(1))) < 1e-3, note
    assert "(correlation 1.0000)" in note


def test_diagnose_says_a_program_that_does_not_fit_before_it_writes_anything(tmp_path, capsys):
    """`diagnose --program` places the program before it creates --out: a record that holds
    the program three times is one line, pointing to --repetitions, and no directory."""
    csv, map_path = _scope(tmp_path, _three_times())
    program = tmp_path / "part.ngc"
    program.write_text(PROGRAM)
    model = tmp_path / "model.yaml"  # the nominal model with the NC the program ran on
    write_with_nc(ModelDoc.load(NOMINAL), model)
    out = tmp_path / "out"
    code = main(["diagnose", str(csv), "--config", str(model), "--map", str(map_path),
                 "--program", str(program), "--out", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "add --repetitions or cut one run with --segment t0:t1" in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_program_whose_rests_miss_the_record_is_refused(tmp_path):
    """Placed, a program whose moves end elsewhere than the record's (one move 25 mm
    further) is refused in one line, not placed with a warning (a real record's rapids were
    missed by 103 mm)."""
    csv, map_path = _scope(tmp_path, PROGRAM)
    run = load_measured(csv, map_path)
    other = PROGRAM.replace("G1 X70 F7200", "G1 X95 F7200")
    assert other != PROGRAM
    program = tmp_path / "other.ngc"
    program.write_text(other)
    nc = yaml.safe_load(NC_CONFIG)["nc"]
    with pytest.raises(MeasuredDataError) as err:
        command_from_program(run, program, nc=nc)
    message = str(err.value)
    assert message.startswith(f"{csv}: the program {program} does not fit the record: placed (")
    miss = re.search(r"it rests ([0-9.]+) mm away from where the axis rests", message)
    # the offset found splits the difference: the rests miss by 10 and 15 mm
    assert miss is not None and 5.0 < float(miss.group(1)) < 25.0, message
    assert "(at most 1 mm fit)" in message and len(message.splitlines()) == 1
    # the program that ran fits
    program.write_text(PROGRAM)
    command_from_program(run, program, nc=nc)
