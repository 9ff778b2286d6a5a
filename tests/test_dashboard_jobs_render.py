"""Each job's dashboard renders headless with every panel showing data (pixel variance per
panel against the same blueprint with no data): the shadow twin, the machine twin, the
LinuxCNC run and `diagnose`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
from rerun_shots import empty_panels, grid_cells, needs_vulkan, render

from feed_twin.machine import dashboard as machine_dash
from feed_twin.shadow import dashboard as shadow_dash
from feed_twin.shadow.health import Verdict
from feed_twin.shadow.twin import ResidualBlock

ROOT = Path(__file__).resolve().parent.parent

pytestmark = [pytest.mark.slow, needs_vulkan]


def _block(t: np.ndarray, *, effort: bool) -> ResidualBlock:
    x_cmd = 0.05 * np.sin(2.0 * t)
    fe = 20e-6 * np.cos(2.0 * t)
    drift = 2e-6 * (t > 102.0)
    effort_meas = (
        100.0 * np.cos(2.0 * t) + 30.0 * (t > 102.0) + np.sin(30 * t)
        if effort
        else np.full_like(t, np.nan)
    )
    effort_twin = 100.0 * np.cos(2.0 * t)
    return ResidualBlock(
        t_s=t,
        x_cmd_m=x_cmd,
        x_meas_m=x_cmd - fe - drift,
        x_twin_m=x_cmd - fe,
        effort_meas=effort_meas,
        effort_twin=effort_twin,
        fe_dev_m=-drift + 1e-7 * np.sin(50 * t),
        effort_dev=effort_meas - effort_twin,
        fe_dev_rms_m=np.abs(drift) + 1e-7,
        effort_dev_rms=np.abs(effort_meas - effort_twin),
        measured_filled=np.zeros(t.size, bool),
        command_filled=np.zeros(t.size, bool),
    )


def _verdict(t: float, level: int, message: str) -> Verdict:
    return Verdict(
        t_s=t, level=level, fe_dev_rms_m=0.0, effort_dev_rms=0.0, baseline_fe_dev_rms_m=0.0,
        baseline_effort_dev_rms=0.0, message=message,
    )  # fmt: skip


@pytest.mark.parametrize("effort", [True, False], ids=["effort", "no-effort"])
def test_the_shadow_dashboard_shows_every_panel(tmp_path: Path, effort: bool) -> None:
    t = 100.0 + np.arange(0.0, 4.0, 1e-3)
    dash = shadow_dash.ShadowDashboard(effort_unit="N", rrd_path=tmp_path / "shadow.rrd")
    for k in range(0, t.size, 500):
        dash.log_block(_block(t[k : k + 500], effort=effort))
        level = 1 if t[k] > 102.5 else 0
        dash.log_verdict(_verdict(float(t[min(k + 499, t.size - 1)]), level,
                                  "guides.F_c changed: +30 N (asymmetric_friction)"))  # fmt: skip
    dash.close()
    layout = shadow_dash.blueprint("N", with_effort=effort)
    rr.RecordingStream("feed_twin_shadow").save(tmp_path / "empty.rrd", default_blueprint=layout)
    columns = shadow_dash.grid_columns(with_effort=effort)
    titles = [title for title, _ in shadow_dash.panels("N", with_effort=effort)]
    plots, log = shadow_dash.ROW_SHARES
    split = plots / (plots + log)
    shots = [render(tmp_path / f"{n}.rrd", tmp_path / f"{n}.png") for n in ("shadow", "empty")]
    full, empty = (
        grid_cells(shot, len(titles), columns, share=(0.0, split))
        + grid_cells(shot, 1, 1, share=(split, 1.0))
        for shot in shots
    )
    assert empty_panels(full, empty, [*titles, "Health"]) == []


def _machine_run():
    """A planned program as the command and a twin a few um off it (duck-typed MachineRun)."""
    from types import SimpleNamespace

    from feed_twin.core.config import load_yaml
    from feed_twin.gcode.config import nc_config_from_mapping
    from feed_twin.gcode.geometry import programmed_path
    from feed_twin.gcode.planner import plan_program

    config = load_yaml(ROOT / "config" / "axis_default.yaml")["nc"]
    nc = nc_config_from_mapping(config, source="axis_default.yaml")
    program = ROOT / "tests" / "fixtures" / "gcode" / "helix.ngc"
    traj = plan_program(program, nc)
    t = traj.t_s
    wobble = 5e-6 * np.sin(40.0 * t)
    actual = traj.pos_m - np.outer(wobble, np.ones(traj.pos_m.shape[1]))
    normal = np.abs(wobble) * (1.0 + np.sin(3.0 * t) ** 2)
    errors = {a: traj.pos_m[:, k] - actual[:, k] for k, a in enumerate(nc.axis_names[:3])}
    # the fields of a MachineRun that write_machine_dashboard reads
    run: Any = SimpleNamespace(
        t_s=t,
        actual=actual,
        simulated=tuple(errors),
        contour=SimpleNamespace(normal_m=normal, lag_m=200e-6 * np.sin(t)),
        following_error=lambda a: errors[a],
    )
    return run, programmed_path(program, nc)


def test_the_machine_dashboard_shows_every_panel(tmp_path: Path) -> None:
    run, segments = _machine_run()
    machine_dash.write_machine_dashboard(run, segments, tmp_path / "machine.rrd")
    blank_frame = machine_dash.PathFrame.around(np.zeros((1, 2)))
    frames = {name: blank_frame for name, _, _ in machine_dash.VIEWS}
    empty = rr.RecordingStream("feed_twin")
    empty.save(tmp_path / "empty.rrd", default_blueprint=machine_dash.machine_blueprint(frames))
    titles: list[str] = list(machine_dash.PANEL_TITLES)
    columns = machine_dash.GRID_COLUMNS
    full = grid_cells(render(tmp_path / "machine.rrd", tmp_path / "m.png"), len(titles), columns)
    blank = grid_cells(render(tmp_path / "empty.rrd", tmp_path / "e.png"), len(titles), columns)
    assert empty_panels(full, blank, titles) == []


def _diagnosis():
    """Traces of an identification and a validation run with a friction the nominal model
    lacks, and the effect named (duck-typed Diagnosis)."""
    from types import SimpleNamespace

    from feed_twin.analysis.report import FoundEffect, Trace

    def trace(label: str, shift: float, friction: float) -> Trace:
        t = np.arange(0.0, 3.0, 1e-3)
        cmd = 0.1 * np.sin(2.0 * t + shift)
        v = 0.2 * np.cos(2.0 * t + shift)
        effort = 50.0 * np.sin(2.0 * t + shift) + 30.0 * np.tanh(v / 1e-3)
        model = effort - friction * np.tanh(v / 1e-3)
        return Trace(label=label, t_s=t, pos_cmd_m=cmd, x_meas_m=cmd - 1e-5 * v / 0.2,
                     x_sim_m=cmd - (1e-5 - friction * 1e-7) * v / 0.2, effort_meas=effort,
                     effort_sim=model, effort_name="force_cmd_N")  # fmt: skip

    effect = FoundEffect(
        name="coulomb_friction", evidence="a force opposing the motion", component="guides",
        parameters={"F_c_N": 29.7}, explained_fraction=0.93,
    )  # fmt: skip
    return SimpleNamespace(
        before_trace=trace("nominal", 0.0, 30.0), after_trace=trace("fitted", 0.0, 0.3),
        validation_traces=(trace("nominal", 1.0, 30.0), trace("fitted", 1.0, 0.3)),
        effects=(effect,), verdict="1 effect found", named_not_fitted=(),
    )  # fmt: skip


def test_the_diagnose_dashboard_shows_every_panel(tmp_path: Path) -> None:
    from feed_twin.analysis import dashboard as diagnose_dash

    d = _diagnosis()
    diagnose_dash.write_rerun(d, tmp_path / "diagnose.rrd")  # type: ignore[arg-type]
    names = [run for run, _, _ in diagnose_dash.runs(d)]  # type: ignore[arg-type]
    panels = diagnose_dash.channels(d.before_trace)
    empty = rr.RecordingStream("feed_twin_diagnose")
    empty.save(tmp_path / "empty.rrd", default_blueprint=diagnose_dash.blueprint(names, panels))
    titles = [f"{c.title}, {run}" for c in panels for run in names]
    plots, text = diagnose_dash.ROW_SHARES
    split = plots / (plots + text)
    shots = [render(tmp_path / f"{n}.rrd", tmp_path / f"{n}.png") for n in ("diagnose", "empty")]
    full, blank = (
        grid_cells(shot, len(titles), len(names), share=(0.0, split))
        + grid_cells(shot, 1, 1, share=(split, 1.0))
        for shot in shots
    )
    assert empty_panels(full, blank, [*titles, "Effects"]) == []


def test_the_linuxcnc_dashboard_shows_every_panel(tmp_path: Path) -> None:
    from feed_twin.linuxcnc import dashboard as cnc_dash

    t = np.arange(0.0, 3.0, 1e-3)
    cmd = np.column_stack([0.05 * np.sin(t), 0.02 * np.sin(2 * t), 0.01 * t])
    error = np.column_stack([2e-6 * np.cos(t), 1e-6 * np.cos(2 * t), 1e-7 * np.ones_like(t)])
    trace = cnc_dash.ServoTrace(
        t_s=t, tick_time_s=1000.0 + t + 20e-6 * np.sin(7.0 * t), joints=("X", "Y", "Z"),
        position_command_m=cmd, position_feedback_m=cmd - error, following_error_m=error,
        servo_output_m_s=np.gradient(cmd, t, axis=0),
    )  # fmt: skip
    cnc_dash.write_linuxcnc_dashboard(
        trace, "X", 1e-3, "LinuxCNC program time: 3.000 s", tmp_path / "cnc.rrd"
    )
    rr.RecordingStream("feed_twin_linuxcnc").save(
        tmp_path / "empty.rrd", default_blueprint=cnc_dash.blueprint("X")
    )
    titles = cnc_dash.panel_titles("X")
    plots, text = cnc_dash.ROW_SHARES
    split = plots / (plots + text)
    shots = [render(tmp_path / f"{n}.rrd", tmp_path / f"{n}.png") for n in ("cnc", "empty")]
    full, blank = (
        grid_cells(shot, len(titles), cnc_dash.GRID_COLUMNS, share=(0.0, split))
        + grid_cells(shot, 1, 1, share=(split, 1.0))
        for shot in shots
    )
    assert empty_panels(full, blank, [*titles, "Run"]) == []
