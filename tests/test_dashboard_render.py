"""The demo dashboard .rrd renders headless with every panel showing its data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rerun_shots import empty_panels, grid_cells, needs_vulkan, render, saturated_fraction

from feed_twin.io.dashboard import GRID_COLUMNS, PANELS, SIGNALS, Dashboard

N_CELLS = len(PANELS) + 1  # and the G-code log
PHASE_PANEL = next(i for i, p in enumerate(PANELS) if p.origin == "/current_phase")


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
    full = grid_cells(render(tmp_path / "run.rrd", tmp_path / "run.png"), N_CELLS, GRID_COLUMNS)
    empty = grid_cells(render(tmp_path / "empty.rrd", tmp_path / "e.png"), N_CELLS, GRID_COLUMNS)
    titles = [p.title for p in PANELS] + ["G-code"]
    assert empty_panels(full, empty, titles) == []
    # the phase currents are waves in their 40 ms window, not a solid band: most of the cell's
    # plot area stays background
    assert saturated_fraction(full[PHASE_PANEL]) < 0.15
