"""ruff on the compiled loop's source, which is written from string templates no linter sees.

The kernel of config/axis_default.yaml (plant module from feed_twin.plant.codegen plus the loop
from feed_twin.sim.kernel) is written to a file and checked with pyflakes, pycodestyle and
bugbear rules. Two rules do not apply to generated code, on purpose:
- E501: the state and parameter tuples are one line each, hundreds of characters long;
- F841: every generated function starts with the same preamble of node variables and each uses
  some of them; LLVM drops the rest.
Everything else (undefined or unused names, imports not at the top, redefinitions, ...) fails.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from feed_twin.control.layout import STRUCTURE_SLOTS, build_cascade
from feed_twin.sim.config import load_axis_config
from feed_twin.sim.kernel import kernel_source

ROOT = Path(__file__).resolve().parents[1]
RUFF = Path(sys.executable).parent / "ruff"


def _ruff(path: Path) -> subprocess.CompletedProcess[str]:
    command = [str(RUFF), "check", "--isolated", "--no-cache", "--select", "E,F,W,B"]
    command += ["--ignore", "E501,F841", str(path)]
    return subprocess.run(command, capture_output=True, text=True, check=False)


@pytest.mark.parametrize("inline", [False, True], ids=["structure-fixed", "inline-parameters"])
def test_the_axis_default_kernel_passes_ruff(tmp_path, inline):
    axis = load_axis_config(ROOT / "config" / "axis_default.yaml")
    cp = build_cascade(axis.controller).params
    if inline:  # engine.inline_parameters: every slot a literal
        p_slots, cp_slots = axis.plant.nominal_params().tolist(), cp.tolist()
    else:  # the engine's default kernel: the controller's structure compiled in
        fixed = {i: float(cp[i]) for i in STRUCTURE_SLOTS}
        p_slots, cp_slots = None, [fixed.get(i) for i in range(len(cp))]
    source = kernel_source(
        axis.plant,
        closed_loop=True,
        substeps=axis.engine.substeps,
        p_slots=p_slots,
        cp_slots=cp_slots,
    )
    path = tmp_path / "kernel.py"
    path.write_text(source)
    result = _ruff(path)
    assert result.returncode == 0, result.stdout + result.stderr


def test_the_check_finds_a_defect_in_generated_source(tmp_path):
    path = tmp_path / "kernel.py"
    path.write_text("from numba import njit\n\n\ndef rhs(x):\n    return x + undefined_slot\n")
    result = _ruff(path)
    assert result.returncode == 1
    assert "F821" in result.stdout and "undefined_slot" in result.stdout
