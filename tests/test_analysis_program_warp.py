"""--program block by block: an NC that waits after each block (exact stop and settle)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.analysis.program import command_from_program
from feed_twin.analysis.synthetic import NC_CONFIG, PROGRAM, generate, write_csv
from feed_twin.analysis.twin import ModelDoc
from feed_twin.io.measured import load_measured

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"
SETTLE_S = 0.065  # the exact-stop settling the issue measured on a Sinumerik, per block


EXACT_STOP = PROGRAM.replace("G64", "G61")  # every block ends at rest


def _as_run(program: str) -> str:
    """The program as the machine ran it: a dwell of SETTLE_S after every move."""
    out = []
    for line in program.splitlines():
        out.append(line)
        if line.startswith("G1 "):
            out.append(f"G4 P{SETTLE_S}")
    return "\n".join(out) + "\n"


@pytest.mark.slow
def test_each_block_is_placed_at_its_own_delay(tmp_path):
    nominal = ModelDoc.load(NOMINAL)
    columns = generate(nominal, {}, program=_as_run(EXACT_STOP))
    truth = columns["x_cmd_mm"] * 1e-3
    scope = {k: v for k, v in columns.items() if k != "x_cmd_mm"}  # no command recorded
    map_path = write_csv(tmp_path / "scope.csv", scope, nominal)
    map_path.write_text(
        map_path.read_text().replace("  pos_cmd_m: {column: x_cmd_mm, unit: mm}\n", "")
    )
    run = load_measured(tmp_path / "scope.csv", map_path)
    program = tmp_path / "part.ngc"
    program.write_text(EXACT_STOP)  # what the user has: the program without the NC's waits
    nc = yaml.safe_load(NC_CONFIG)["nc"]
    placed = command_from_program(run, program, nc=nc, model=nominal)
    note = placed.warnings[-1]
    assert "aligned block by block: 9 moves" in note, note  # the program's nine G1 blocks
    error = np.abs(placed["pos_cmd_m"] - truth)
    # within the positioning moves' own interpolation: v_max * a few tenths of a sample
    assert np.max(error) < 0.12 * 5e-4
    # the blocks fall later and later: 65 ms more per block before each move
    moves = int(note.split("block by block: ")[1].split(" moves")[0])
    late = float(note.split("the last ")[1].split(" ms")[0])
    assert late == pytest.approx(1e3 * (moves - 1) * SETTLE_S, rel=0.05)
    # and the note says what to put in the NC config to plan the waits
    assert "a median 65 ms per block: nc.exact_stop_settle_s plans" in note, note
