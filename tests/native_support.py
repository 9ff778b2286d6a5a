"""Paths of the C-backend tests."""

from __future__ import annotations

from pathlib import Path

from feed_twin.native.program import program_ref

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "tests" / "fixtures" / "gcode" / "sample.ngc"

__all__ = ["ROOT", "SAMPLE", "program_ref"]
