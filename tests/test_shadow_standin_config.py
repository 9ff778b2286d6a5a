"""The stand-in's config (`shadow.standin`) and the error paths of `run --shadow` that stop
before any node starts, and of the shadow summary."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from feed_twin.cli import main as cli_main
from feed_twin.core.config import ConfigError
from feed_twin.io.bag import BagWriter
from feed_twin.shadow.config import FrictionStep, load_shadow_config
from feed_twin.shadow.summary import summarise_shadow

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
PROGRAM = "%\nG21 G90 G54\nG1 X10 F3000\nM30\n%\n"


def axis_with(tmp_path: Path, edit) -> Path:
    data = yaml.safe_load(AXIS.read_text())
    edit(data)
    path = tmp_path / "axis.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_standin_section_is_optional_and_read_when_given() -> None:
    data = yaml.safe_load((ROOT / "config" / "emps.yaml").read_text())
    del data["shadow"]["standin"]
    emps = load_shadow_config(data, source="emps.yaml").standin  # no standin: the defaults
    assert (emps.jitter_s, emps.current_lag_s, emps.coupling_stiffness_factor) == (
        2e-4, 2e-4, 0.97,
    )  # fmt: skip
    assert emps.effort_noise_std is None and dict(emps.hidden) == {} and not emps.friction_steps
    data = yaml.safe_load(AXIS.read_text())
    data["shadow"]["standin"].update(
        hidden={"coulomb_friction": {"F_c_N": 150.0}},
        friction_steps=[{"at_s": 1.0, "scale": 1.5}, {"at_s": 2.0, "scale": 2.0}],
    )
    cfg = load_shadow_config(data, source="axis.yaml").standin
    assert dict(cfg.hidden["coulomb_friction"]) == {"F_c_N": 150.0}
    assert cfg.friction_steps == (
        FrictionStep(at_s=1.0, scale=1.5),
        FrictionStep(at_s=2.0, scale=2.0),
    )
    assert cfg.effort_noise_std == 0.01
    with pytest.raises(TypeError):
        cfg.hidden["mass_error"] = {"m_kg": 1.0}  # frozen like the rest of the config
    um = cfg.unmodelled()
    assert (um.current_lag_s, um.effort_noise_std, um.seed) == (2e-4, 0.01, 0)


@pytest.mark.parametrize(
    ("standin", "message"),
    [
        (
            {"hidden": {"worn_screw": {}}},
            "shadow.standin.hidden.worn_screw: unknown effect; one of",
        ),
        (
            {"hidden": {"coulomb_friction": {"F_c_N": "high"}}},
            "shadow.standin.hidden.coulomb_friction = {'F_c_N': 'high'}: must be a mapping "
            "parameter -> number",
        ),
        ({"hidden": [1]}, "shadow.standin.hidden = [1]: must be a mapping effect ->"),
        (
            {"friction_steps": [{"at_s": 3.0, "scale": 2.0}, {"at_s": 1.0, "scale": 1.5}]},
            "shadow.standin.friction_steps: at_s = [3.0, 1.0]: must be in increasing order",
        ),
        (
            {"friction_steps": [{"at_s": 1.0, "scale": 0.0}]},
            "shadow.standin.friction_steps[0].scale = 0.0: must be > 0",
        ),
        (
            {"friction_steps": [{"at_s": -1.0, "scale": 2.0}]},
            "shadow.standin.friction_steps[0].at_s = -1.0: must be >= 0",
        ),
        ({"jitter_s": -1e-4}, "shadow.standin.jitter_s = -0.0001: must be >= 0"),
        ({"current_lag_s": -1.0}, "shadow.standin.current_lag_s = -1.0: must be >= 0"),
        ({"effort_noise_std": -0.1}, "shadow.standin.effort_noise_std = -0.1: must be >= 0"),
        ({"latency_s": 1.0}, "shadow.standin: unknown key(s) latency_s; allowed: jitter_s"),
    ],
)
def test_standin_section_errors_name_the_field(standin: dict, message: str) -> None:
    data = yaml.safe_load(AXIS.read_text())
    data["shadow"]["standin"] = standin
    with pytest.raises(ConfigError) as err:
        load_shadow_config(data, source="axis.yaml")
    assert str(err.value).startswith(f"axis.yaml: {message}")


def run_cli(tmp_path: Path, config: Path, *extra: str) -> int:
    program = tmp_path / "move.ngc"
    program.write_text(PROGRAM)
    return cli_main(
        ["run", str(program), "--config", str(config), "--shadow", "--out", str(tmp_path / "o"),
         "--json", *extra]
    )  # fmt: skip


def test_shadow_run_needs_separate_processes_and_the_gcode_node(tmp_path, capsys) -> None:
    for flag in ("--single-process", "--no-gcode"):
        assert run_cli(tmp_path, AXIS, flag) == 1
        out, err = capsys.readouterr()
        assert (
            "--shadow runs the G-code node, the stand-in machine and the twin as separate "
            "processes: it cannot be combined with --single-process or --no-gcode"
        ) in err
        assert json.loads(out.strip().splitlines()[-1])["exit_code"] == 1
    assert not (tmp_path / "o").exists()  # nothing started, nothing written


def test_shadow_run_starts_every_node_here(tmp_path, capsys) -> None:
    assert run_cli(tmp_path, AXIS, "--start", "twin") == 1
    out, err = capsys.readouterr()
    assert err.strip() == (
        "feed-twin run: --start: not available for an axis's shadow node set (it starts every "
        "node here)"
    )
    assert json.loads(out.strip().splitlines()[-1])["mode"] == "axis nodes shadow"
    assert not (tmp_path / "o").exists()  # nothing started, nothing written


def test_shadow_run_without_a_shadow_section_stops_before_starting(tmp_path, capsys) -> None:
    config = axis_with(tmp_path, lambda d: d.pop("shadow"))
    assert run_cli(tmp_path, config) == 1
    assert f"{config}: missing required section shadow" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_shadow_period_must_be_the_nc_period(tmp_path, capsys) -> None:
    def edit(d: dict) -> None:
        d["shadow"]["sample_period_s"] = 2e-3
        d["shadow"]["window_s"] = 1.0  # still >= 10 samples

    config = axis_with(tmp_path, edit)
    assert run_cli(tmp_path, config) == 1
    assert (
        f"{config}: shadow.sample_period_s = 0.002: must equal nc.interpolation_period_s = 0.001 "
        "(the twin shadows the NC's command stream)"
    ) in capsys.readouterr().err


def test_standin_node_rejects_bad_arguments_before_compiling(capsys) -> None:
    from feed_twin.ros.standin_node import main

    assert main(["--config", str(AXIS), "--jitter", "-0.001"]) == 1
    assert "standin node: --jitter -0.001: must be >= 0" in capsys.readouterr().err
    assert main(["--config", str(AXIS), "--follow", "--period", "0.002"]) == 1
    assert (
        f"standin node: {AXIS}: nc.interpolation_period_s = 0.001: the stand-in plays one NC "
        "sample per machine cycle (0.002 s)"
    ) in capsys.readouterr().err


def test_summary_of_a_bag_without_the_twin_says_so(tmp_path) -> None:
    with BagWriter(tmp_path / "bag", flush_period_s=None) as writer:
        writer.add_topic("/cnc/x/command", "feed_twin_msgs/msg/AxisCommand")
    with pytest.raises(ValueError, match="the bag has no /cnc/x/twin/residual messages: the twin "
                                         "shadowed nothing"):  # fmt: skip
        summarise_shadow(
            tmp_path / "bag", command_topic="/cnc/x/command", twin_namespace="/cnc/x/twin",
            effort_unit="A",
        )  # fmt: skip
