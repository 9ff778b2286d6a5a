"""The live viewer in a real browser: headless Chromium (Debian's, installed by tools/setup.sh)
driven by Playwright loads the page `--live` prints, connects to the gRPC server and draws the
run's data."""

from __future__ import annotations

import shutil
import time

import matplotlib.image as mpimg
import numpy as np
import pytest
from rerun_shots import grid_cells, saturated_fraction

from feed_twin.io.dashboard import GRID_COLUMNS, PANELS, Dashboard
from feed_twin.io.live import LiveViewer

CHROMIUM = shutil.which("chromium")
FE_PANEL = next(i for i, p in enumerate(PANELS) if p.origin == "/following_error")


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="needs Chromium: tools/setup.sh installs it")
def test_the_live_page_loads_connects_and_shows_the_data(tmp_path) -> None:
    from playwright.sync_api import sync_playwright

    viewer = LiveViewer()
    try:
        t = np.arange(0.0, 2.0, 1e-3)
        with Dashboard(rrd_path=None, live_url=viewer.grpc_url) as dash:
            dash.log_columns(
                t, {"x_m": 0.05 * np.sin(t), "following_error_m": 1e-5 * np.cos(3 * t)}
            )
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=CHROMIUM,
                args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
            )
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(viewer.web_url)
            page.wait_for_selector("canvas", timeout=60_000)
            fraction, deadline = 0.0, time.monotonic() + 60.0
            while fraction < 0.002 and time.monotonic() < deadline:
                time.sleep(1.0)
                page.screenshot(path=str(tmp_path / "live.png"))
                shot = mpimg.imread(tmp_path / "live.png")[..., :3]
                cells = grid_cells(shot, len(PANELS) + 1, GRID_COLUMNS)
                fraction = saturated_fraction(cells[FE_PANEL])
            browser.close()
    finally:
        viewer.stop()
    # the following error's red curve crosses its panel: the page got the data over gRPC
    assert fraction >= 0.002
