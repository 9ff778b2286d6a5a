"""Measured-record files for the import tests: a text file, and columns as a CSV (NaN as an
empty cell, as a recorder writes a missing sample)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_file(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def write_csv(tmp_path: Path, cols: dict[str, np.ndarray], name: str = "run.csv") -> Path:
    names = list(cols)
    rows = np.column_stack([cols[k] for k in names])
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in rows]
    return write_file(tmp_path, name, "\n".join(lines).replace("nan", "") + "\n")
