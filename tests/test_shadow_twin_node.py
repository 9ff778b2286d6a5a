"""The twin node in-process (no peers, no DDS traffic): a health verdict that rises from WARN to
ERROR is published and logged both times (rclpy refuses a log call site whose severity changes,
which used to kill the twin at the first ERROR after a WARN)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.ros.dds import init_context
from feed_twin.shadow.health import ERROR, OK, WARN, Verdict
from feed_twin.shadow.standin import write_map

pytestmark = [pytest.mark.ros]
CONFIG = Path("config/emps.yaml")


def verdict(level: int, t_s: float) -> Verdict:
    return Verdict(
        t_s=t_s, level=level, fe_dev_rms_m=1e-6, effort_dev_rms=2.0, baseline_fe_dev_rms_m=1e-7,
        baseline_effort_dev_rms=0.5, message=f"level {level} at {t_s}",
    )  # fmt: skip


def test_rising_verdicts_are_published_and_logged_without_killing_the_node(tmp_path) -> None:
    from feed_twin.ros import twin_node

    map_path = write_map(tmp_path / "map.yaml", Twin.compile(ModelDoc.load(CONFIG)), "/cnc/x")
    parser = argparse.ArgumentParser()
    twin_node.configure(parser)
    args = parser.parse_args(["--config", str(CONFIG), "--map", str(map_path)])
    context = init_context()
    try:
        node = twin_node.build(args, context)
        sent: list[bytes] = []
        node._health_pub.publish = sent.append  # what goes out on <ns>/twin/health
        for level, t_s in ((WARN, 1.0), (ERROR, 2.0), (WARN, 3.0), (OK, 4.0), (ERROR, 5.0)):
            node._verdict(verdict(level, t_s))
        assert len(sent) == 5
        assert not node.done
        node.liveness.stop()
        node.destroy_node()
    finally:
        context.try_shutdown()
