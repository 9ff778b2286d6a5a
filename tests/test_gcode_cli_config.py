"""`feed-twin plan` end to end, and the `nc:` config loader with every error message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.cli import main as cli_main
from feed_twin.core.config import ConfigError
from feed_twin.gcode import load_nc_config, plan_program

FIXTURES = Path(__file__).parent / "fixtures" / "gcode"
CONFIG_FILE = FIXTURES / "nc_test.yaml"
ROOT = Path(__file__).parent.parent


def test_plan_writes_the_csv_and_prints_a_summary(tmp_path, capsys):
    out = tmp_path / "traj.csv"
    program = FIXTURES / "square_metric_abs.ngc"
    assert cli_main(["plan", str(program), "--config", str(CONFIG_FILE), "--out", str(out)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header == [
        "t_s",
        *("x_m", "vx_m_s", "ax_m_s2", "y_m", "vy_m_s", "ay_m_s2", "z_m", "vz_m_s", "az_m_s2"),
        "line",
    ]
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    traj = plan_program(program, load_nc_config(CONFIG_FILE))
    assert table.shape == (len(traj), 11)
    np.testing.assert_allclose(table[:, 0], traj.t_s, atol=1e-12)
    np.testing.assert_allclose(table[:, 1:10:3], traj.pos_m, rtol=1e-11, atol=1e-15)
    np.testing.assert_allclose(table[:, 2:10:3], traj.vel_m_s, rtol=1e-11, atol=1e-15)
    np.testing.assert_allclose(table[:, 3:10:3], traj.acc_m_s2, rtol=1e-11, atol=1e-15)
    np.testing.assert_array_equal(table[:, 10], traj.line)
    text = capsys.readouterr().out
    assert f"cycle time   {traj.t_s[-1]:.3f} s ({len(traj)} samples at 0.001 s)" in text
    # G0 Z5, plunge 5, square 160, retract 5 mm (exact stops: samples nearly on the corners)
    assert "path length  175.000 mm (sampled)" in text
    assert "X              0.05000     3.000" in text  # F3000 on the long sides


def test_plan_reports_program_and_config_errors_with_exit_code_2(tmp_path, capsys):
    bad = tmp_path / "bad.ngc"
    bad.write_text("G21\nG93 G1 X1 F1\n")
    out = tmp_path / "never.csv"
    assert cli_main(["plan", str(bad), "--config", str(CONFIG_FILE), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert (
        err.strip()
        == f"feed-twin plan: {bad}:2:1: word 'G93': unsupported mode (inverse-time feed)"
    )
    assert not out.exists()
    config = tmp_path / "axis.yaml"
    config.write_text("plant: {}\n")
    assert cli_main(["plan", str(bad), "--config", str(config)]) == 2
    assert "no 'nc' section (top-level keys: plant)" in capsys.readouterr().err


def test_default_config_is_a_valid_machining_centre():
    config = load_nc_config(ROOT / "config" / "axis_default.yaml")
    assert config.axis_names == ("X", "Y", "Z")
    assert config.twin_axis == "X" and config.profile == "jerk"
    assert config.interpolation_period_s == 1e-3
    traj = plan_program(FIXTURES / "sample.ngc", config)
    assert traj.axis("X")[0].shape == (len(traj),)
    with pytest.raises(KeyError, match=r"axis 'A' is not planned; axes are \('X', 'Y', 'Z'\)"):
        traj.axis("A")


def _config_with(tmp_path, edit) -> Path:
    data = yaml.safe_load(CONFIG_FILE.read_text())
    edit(data["nc"])
    path = tmp_path / "nc.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda nc: nc.update(speed=1), "nc: unknown key(s) speed; allowed: axes"),
        (
            lambda nc: nc["axes"][1].update(a_max_m_s2=-1.0),
            "nc.axes[1].a_max_m_s2 = -1.0: must be > 0",
        ),
        (
            lambda nc: nc["axes"][0].update(name="Q"),
            "nc.axes[0].name = 'Q': must be one of X, Y, Z, U, V, W",
        ),
        (
            lambda nc: nc["axes"][0].update(travel_max_m=-0.6),
            "nc.axes[0].travel_max_m = -0.6: must be > travel_min_m = -0.5",
        ),
        (lambda nc: nc["axes"].pop(2), "nc.axes = ('X', 'Y'): axis Z is required"),
        (lambda nc: nc.update(twin_axis="B"), "nc.twin_axis = 'B': must be one of ('X', 'Y', 'Z')"),
        (
            lambda nc: nc.update(start_position_m=[0.0, 0.9, 0.0]),
            "nc.start_position_m[1] = 0.9: outside the travel of axis Y [-0.5, 0.5]",
        ),
        (
            lambda nc: nc["work_offsets_m"].update(G57=[0.0, 0.0]),
            "nc.work_offsets_m.G57 = (0.0, 0.0): needs 3 entries (one per axis)",
        ),
        (lambda nc: nc.update(profile="cubic"), "nc.profile = 'cubic': must be one of 'jerk',"),
        (lambda nc: nc.update(path_tolerance_m=0.0), "nc.path_tolerance_m = 0.0: must be > 0"),
        (
            lambda nc: nc.update(lookahead_segments=4),
            "nc.lookahead_segments = 4: must be >= 8",
        ),
        (
            lambda nc: nc.update(interpolation_period_s=-1e-3),
            "nc.interpolation_period_s = -0.001: must be > 0",
        ),
        (
            lambda nc: nc.update(exact_stop_settle_s=-0.065),
            "nc.exact_stop_settle_s = -0.065: must be >= 0",
        ),
    ],
)
def test_config_errors_name_the_file_and_field(tmp_path, edit, message):
    path = _config_with(tmp_path, edit)
    with pytest.raises(ConfigError) as info:
        load_nc_config(path)
    assert str(info.value).startswith(f"{path}: {message}")
