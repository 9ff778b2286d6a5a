"""The shadow twin node beside the stand-in node over DDS (feed-twin shadow), in real time.

Both nodes run as separate processes in a private ROS domain; `run_shadow` kills them in a
`finally` and bounds every wait. Timing on a shared 2-core machine is what it is: these tests
check that nothing is lost, that the lag does not grow and memory stays bounded, and what the
health verdict says; the lag figures themselves are benchmarks (benchmarks/replay_speed.py).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from feed_twin.ros.shadow_cli import run_shadow

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def shadow(tmp_path: Path, duration: float, raise_at: float | None = None) -> dict:
    args = argparse.Namespace(
        config=Path("config/emps.yaml"),
        duration=duration,
        raise_friction_at=raise_at,
        friction_scale=1.35,
        jitter=2e-4,
        out=tmp_path,
        live=False,
    )
    code, report, err = run_shadow(args)
    assert code == 0, err[-3000:]
    assert report is not None, err[-3000:]
    return report


def test_shadow_keeps_up_with_a_1khz_standin_for_60_s(tmp_path) -> None:
    report = shadow(tmp_path, 60.0)
    n = 60_000
    assert report["samples"] == n
    for kind in ("command", "measured"):
        faults = report["faults"][kind]
        assert faults["received"] == n, faults  # reliable transport: nothing lost
        assert faults["missing"] == 0 and faults["late"] == 0, faults
    # no growing lag: the end of the run is not behind its start
    assert report["lag_ms_last_p50"] < report["lag_ms_first_p50"] + 5.0, report
    # bounded memory: buffers are rings and bounded queues (the lag record itself is 5 MB)
    assert report["rss_mb"]["end"] - report["rss_mb"]["start"] < 40.0, report["rss_mb"]
    assert report["warnings"] == 0, report["last"]


def test_raised_friction_fires_the_warning_and_names_it(tmp_path) -> None:
    report = shadow(tmp_path, 20.0, raise_at=10.0)
    last = report["last"]
    assert last["level"] == "WARN", last
    assert last["effect"] == "coulomb_friction", last
    assert last["relative_change"] == pytest.approx(0.35, abs=0.05)
    assert (tmp_path / "shadow.rrd").stat().st_size > 10_000
