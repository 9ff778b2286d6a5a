"""Dashboard layout and error messages (no rendering)."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest

from feed_twin.io.dashboard import PANELS, SERIES, SIGNALS, Dashboard, blueprint
from feed_twin.io.live import LiveViewer


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


def test_live_options_are_checked_and_a_public_address_warned(capsys) -> None:
    import argparse

    from feed_twin.io.live import add_live_options, is_loopback, start_live

    parser = argparse.ArgumentParser()
    add_live_options(parser)
    with pytest.raises(ValueError, match=r"^--live-port 70000: must lie in \[1, 65534\]$"):
        start_live(parser.parse_args(["--live", "--live-port", "70000"]))
    with pytest.raises(ValueError, match=r"^--live-linger -1: must be >= 0 s$"):
        start_live(parser.parse_args(["--live", "--live-linger", "-1"]))
    assert start_live(parser.parse_args([])) is None
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")


@pytest.mark.slow
def test_the_live_viewer_on_every_interface_is_warned_and_lingers(capsys) -> None:
    import argparse
    import time

    from feed_twin.io.live import add_live_options, linger, start_live

    parser = argparse.ArgumentParser()
    add_live_options(parser)
    args = parser.parse_args(["--live", "--live-addr", "0.0.0.0", "--live-linger", "0.5"])
    viewer = start_live(args)
    assert viewer is not None
    try:
        out, err = capsys.readouterr()
        assert err.startswith("warning: the live viewer listens on 0.0.0.0 (ports ")
        assert "not on loopback" in err
        assert out.startswith(f"live: http://{socket.gethostname()}:{viewer.web_port}/?url=")
        began = time.monotonic()
        linger(viewer, args.live_linger)
        assert 0.4 < time.monotonic() - began < 5.0
        assert not viewer.running()
    finally:
        viewer.stop()


def test_no_run_mode_refuses_live() -> None:
    # every mode serves its dashboards: the axis modes stream, the machine modes show theirs
    # once written (feed_twin.io.live.show_recording)
    from feed_twin.machine.run_cli import NODE_SET_OPTIONS
    from feed_twin.ros.machine_run import REFUSED as MACHINE_NODES_REFUSE
    from feed_twin.ros.machine_shadow_run import REFUSED as MACHINE_SHADOW_REFUSES

    for refused in (NODE_SET_OPTIONS, MACHINE_NODES_REFUSE, MACHINE_SHADOW_REFUSES):
        assert not {"live", "live_addr", "live_port", "live_linger"} & set(refused)
