"""Dashboard layout and error messages (no rendering)."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from feed_twin.io.dashboard import PANELS, SERIES, SIGNALS, Dashboard, LiveViewer, blueprint


def test_layout_covers_the_signals_the_issue_names() -> None:
    titles = [p.title for p in PANELS]
    assert titles == [
        "Position [mm]",
        "Following error [um]",
        "Velocity [mm/s]",
        "dq currents [A]",
        "Phase currents, last 40 ms [A]",
        "dq voltages [V]",
        "DC bus [V]",
        "Friction force [N]",
    ]
    assert len(SIGNALS) == len(set(SIGNALS)) == 16
    # Display units: mm for positions and velocities, um for the following error.
    assert SERIES["x_m"].scale == 1e3 and SERIES["following_error_m"].scale == 1e6
    assert blueprint() is not None


def test_error_messages(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"needs an rrd_path, a live_url or both"):
        Dashboard(rrd_path=None)
    with pytest.raises(ValueError, match=r"batch = 0: must be a whole number >= 1"):
        Dashboard(rrd_path=tmp_path / "a.rrd", batch=0)
    with Dashboard(rrd_path=tmp_path / "b.rrd") as dash:
        with pytest.raises(KeyError, match=r"unknown dashboard signal\(s\) speed; known: x_cmd_m"):
            dash.append(0.0, {"speed": 1.0})
        with pytest.raises(ValueError, match=r"signal 'x_m' has 2 samples, the time column 3"):
            dash.log_columns([0.0, 1.0, 2.0], {"x_m": [1.0, 2.0]})
        with pytest.raises(KeyError, match=r"unknown dashboard signal 'y_m'"):
            dash.log_columns([0.0], {"y_m": [1.0]})
    assert (tmp_path / "b.rrd").stat().st_size > 0


@pytest.mark.slow
def test_live_viewer_listens_on_loopback_only(tmp_path: Path) -> None:
    viewer = LiveViewer()
    try:
        listening = subprocess.run(
            ["ss", "-ltn"], capture_output=True, text=True, timeout=10
        ).stdout
        for port in (viewer.grpc_port, viewer.web_port):
            lines = [ln for ln in listening.splitlines() if f":{port} " in ln]
            assert lines, f"port {port} is not listening"
            assert all("127.0.0.1:" in ln for ln in lines), lines
        with Dashboard(rrd_path=tmp_path / "live.rrd", live_url=viewer.grpc_url) as dash:
            dash.log_columns(np.arange(3) * 1e-3, {"x_m": [0.0, 1e-3, 2e-3]})
        with socket.create_connection(("127.0.0.1", viewer.web_port), timeout=5):
            pass
        assert viewer.web_url.startswith(f"http://127.0.0.1:{viewer.web_port}/?url=")
    finally:
        viewer.stop()
    assert (tmp_path / "live.rrd").stat().st_size > 0
