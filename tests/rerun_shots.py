"""Headless screenshots of a Rerun recording and its panels, for the dashboard render tests.

The viewer runs with Vulkan on Mesa's lavapipe (no display); the recording is streamed on
standard input, which renders it whole where a file opened by path may still show "Loading..."
when the screenshot is taken (/work/shared/ROS_NOTES.md). A dashboard whose blueprint is a grid
of `columns` is cut into its cells; a panel has data when its cell differs from the same cell
rendered from the blueprint alone (pixel variance), or shows saturated series colours.
"""

from __future__ import annotations

import glob
import os
import subprocess
import tempfile
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from feed_twin.io.dashboard import rerun_binary

# Relative layout of the viewer at 1400x900 with the side panels collapsed: a top bar, then
# the grid, then the time panel. Measured once from a render; the cells are large compared to
# any error in these fractions.
TOP, BOTTOM = 0.045, 0.965
WINDOW = "1400x900"

needs_vulkan = pytest.mark.skipif(
    not glob.glob("/usr/share/vulkan/icd.d/lvp_icd*.json"),
    reason="headless Rerun needs Vulkan (lavapipe): apt-get install mesa-vulkan-drivers",
)


def render(rrd: Path, png: Path) -> np.ndarray:
    """The viewer's screenshot of `rrd` (RGB floats in [0, 1])."""
    runtime = tempfile.mkdtemp(prefix="xdg-")
    env = {**os.environ, "XDG_RUNTIME_DIR": runtime, "RERUN_ANALYTICS": "false"}
    with rrd.open("rb") as stream:
        subprocess.run(
            [str(rerun_binary()), "--headless", "--window-size", WINDOW,
             "--screenshot-to", str(png), "-"],
            stdin=stream, check=True, timeout=90, capture_output=True, env=env,
        )  # fmt: skip
    return mpimg.imread(png)[..., :3]


def grid_cells(
    image: np.ndarray, n: int, columns: int, *, share: tuple[float, float] = (0.0, 1.0)
) -> list[np.ndarray]:
    """The `n` cells of a grid of `columns`, row by row, in the `share` (from, to) of the
    viewer's height the grid takes (a grid above a full-width panel takes (0, 0.75))."""
    h, w, _ = image.shape
    rows = (n + columns - 1) // columns
    area_top, area_bottom = int(TOP * h), int(BOTTOM * h)
    top = area_top + int(share[0] * (area_bottom - area_top))
    bottom = area_top + int(share[1] * (area_bottom - area_top))
    out = []
    for k in range(n):
        r, c = divmod(k, columns)
        y0 = top + (bottom - top) * r // rows
        y1 = top + (bottom - top) * (r + 1) // rows
        x0 = w * c // columns
        # a margin inside the cell: its title bar and borders are drawn either way
        y0 += (y1 - y0) // 8
        out.append(image[y0:y1, x0 : x0 + w // columns])
    return out


def saturated_fraction(cell: np.ndarray) -> float:
    """Share of saturated pixels: series colours are saturated, the viewer's chrome is grey."""
    return float(((cell.max(axis=-1) - cell.min(axis=-1)) > 0.3).mean())


def changed_fraction(cell: np.ndarray, empty: np.ndarray) -> float:
    """Share of pixels that differ from the blueprint-only render of the same cell."""
    return float((np.abs(cell - empty).max(axis=-1) > 0.1).mean())


def empty_panels(
    full: list[np.ndarray], empty: list[np.ndarray], titles: list[str], *, least: float = 0.002
) -> list[str]:
    """Titles of the panels whose cell shows no more than the blueprint alone does."""
    return [
        title
        for title, a, b in zip(titles, full, empty, strict=True)
        if changed_fraction(a, b) < least and saturated_fraction(a) <= saturated_fraction(b)
    ]
