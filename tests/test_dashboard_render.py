"""The dashboard .rrd renders headless with every plot panel showing its curves."""

from __future__ import annotations

import glob
import subprocess
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from feed_twin.io.dashboard import GRID_COLUMNS, PANELS, SIGNALS, Dashboard, rerun_binary

# Relative layout of the viewer at 1400x900 with the side panels collapsed: a top bar, then
# the grid, then the time panel. Measured once from a render; the cells are large compared to
# any error in these fractions.
TOP, BOTTOM = 0.045, 0.965
ROWS = (len(PANELS) + 1 + GRID_COLUMNS - 1) // GRID_COLUMNS


def sample_run(t: np.ndarray) -> dict[str, np.ndarray]:
    """A smooth 50 mm move with plausible drive signals, to give every panel a curve."""
    x = 0.05 * (1.0 - np.cos(np.pi * t)) / 2.0
    v = 0.05 * np.pi / 2.0 * np.sin(np.pi * t)
    theta_e = 2.0 * np.pi * 4.0 * x / 0.01  # 4 pole pairs, 10 mm lead
    i_q = 3.0 * np.cos(np.pi * t)
    return {
        "x_cmd_m": x,
        "x_m": x - 1e-5 * np.sin(np.pi * t),
        "following_error_m": 1e-5 * np.sin(np.pi * t),
        "v_cmd_m_s": v,
        "v_m_s": 0.99 * v,
        "i_q_ref_A": i_q,
        "i_q_A": i_q + 0.05,
        "i_d_ref_A": np.zeros_like(t),
        "i_d_A": 0.02 * np.sin(50.0 * t),
        "i_a_A": -i_q * np.sin(theta_e),
        "i_b_A": -i_q * np.sin(theta_e - 2.0 * np.pi / 3.0),
        "i_c_A": -i_q * np.sin(theta_e + 2.0 * np.pi / 3.0),
        "u_d_V": 2.0 * np.sin(t),
        "u_q_V": 40.0 * v / 0.08 + 1.5 * i_q,
        "u_dc_V": np.full_like(t, 560.0),
        "f_friction_N": 50.0 * np.tanh(v / 1e-3),
    }


def render(rrd: Path, png: Path) -> np.ndarray:
    subprocess.run(
        [
            str(rerun_binary()),
            "--headless",
            "--window-size",
            "1400x900",
            "--screenshot-to",
            str(png),
            str(rrd),
        ],
        check=True,
        timeout=60,
        capture_output=True,
    )
    return mpimg.imread(png)[..., :3]


def cells(image: np.ndarray) -> list[np.ndarray]:
    h, w, _ = image.shape
    top, bottom = int(TOP * h), int(BOTTOM * h)
    out = []
    for k in range(len(PANELS) + 1):
        r, c = divmod(k, GRID_COLUMNS)
        y0 = top + (bottom - top) * r // ROWS
        y1 = top + (bottom - top) * (r + 1) // ROWS
        x0 = w * c // GRID_COLUMNS
        # The left 45 % of a cell: curves cross it, legends (bottom right) and viewer
        # notifications (top right of the window) do not.
        x1 = x0 + int(0.45 * w / GRID_COLUMNS)
        out.append(image[y0:y1, x0:x1])
    return out


def saturated_fraction(cell: np.ndarray) -> float:
    # Series colours are saturated; the viewer's background, grid and text are grey.
    return float(((cell.max(axis=-1) - cell.min(axis=-1)) > 0.3).mean())


def bright_fraction(cell: np.ndarray) -> float:
    return float((cell.max(axis=-1) > 0.6).mean())


needs_vulkan = pytest.mark.skipif(
    not glob.glob("/usr/share/vulkan/icd.d/lvp_icd*.json"),
    reason="headless Rerun needs Vulkan (lavapipe): apt-get install mesa-vulkan-drivers",
)


@pytest.mark.slow
@needs_vulkan
def test_every_plot_panel_shows_curves(tmp_path: Path) -> None:
    t = np.arange(0.0, 2.0, 1e-3)
    data = sample_run(t)
    assert set(data) == set(SIGNALS)
    with Dashboard(rrd_path=tmp_path / "run.rrd", batch=200) as dash:
        for k in range(0, t.size, 2):
            dash.append(float(t[k]), {name: float(v[k]) for name, v in data.items()})
        dash.log_gcode_line(0.0, 1, "G1 X50 F3000")
        dash.log_gcode_line(1.0, 2, "G1 X0")
    with Dashboard(rrd_path=tmp_path / "empty.rrd"):
        pass
    # The viewer takes its screenshot after a fixed number of frames; on a busy machine the
    # recording may still be loading then ("Loading..."), so a blank first render is retried.
    for attempt in range(3):
        full = cells(render(tmp_path / "run.rrd", tmp_path / f"run{attempt}.png"))
        if saturated_fraction(full[0]) > 0.0:
            break
    empty = cells(render(tmp_path / "empty.rrd", tmp_path / "empty.png"))
    for panel, with_data, without in zip(PANELS, full, empty, strict=False):
        # A curve across a cell covers more than 0.05 % of it (a flat one about 0.1 %); a
        # blank plot has no saturated pixels at all.
        assert saturated_fraction(without) < 0.0001, panel.title
        assert saturated_fraction(with_data) > 0.0005, panel.title
    assert bright_fraction(full[-1]) > bright_fraction(empty[-1]) + 0.001, "G-code log is empty"
