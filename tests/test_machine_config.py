"""The machine YAML: the NC once, a plant + drive per simulated axis (included by reference), a
vertical axis's weight and counterbalance, and one-line errors before anything moves."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.core.config import ConfigError
from feed_twin.gcode import GcodeError, load_nc_config
from feed_twin.gcode.planner import validate_program
from feed_twin.machine.config import is_machine_config, load_machine_config
from feed_twin.sim.config import build_engine

ROOT = Path(__file__).resolve().parents[1]
MACHINE = ROOT / "config" / "machine_default.yaml"
AXIS = ROOT / "config" / "axis_default.yaml"


def write_machine(tmp_path: Path, **changes) -> Path:
    data = yaml.safe_load(MACHINE.read_text())
    for key, value in changes.items():
        if value is None:
            data.pop(key, None)
        else:
            data[key] = value
    (tmp_path / "axis_default.yaml").write_text(AXIS.read_text())
    path = tmp_path / "machine.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_default_machine_simulates_x_y_z_and_plans_b_as_a_command():
    machine = load_machine_config(MACHINE)
    assert machine.simulated == ("X", "Y", "Z")
    assert machine.nc.axis_names == ("X", "Y", "Z", "B")
    assert machine.nc.twin_axis == "X"
    assert "gravity" in machine.axes["Z"].plant.components
    assert "counterbalance" in machine.axes["Z"].plant.components
    assert "gravity" not in machine.axes["X"].plant.components
    assert is_machine_config(yaml.safe_load(MACHINE.read_text()))
    assert not is_machine_config(yaml.safe_load(AXIS.read_text()))
    assert machine.select(["x", "Z"]).simulated == ("X", "Z")


def test_single_axis_config_keeps_working():
    nc = load_nc_config(AXIS)
    assert nc.axis_names == ("X", "Y", "Z")
    assert nc.start_position == nc.start_position_m


def holding_current(machine_path: Path, axis: str = "Z") -> float:
    """Mean q-current [A] over the last 0.3 s of holding the axis at s = 0 for 1 s."""
    machine = load_machine_config(machine_path)
    engine = build_engine(machine.axes[axis], record=["motor.i_q", "table.s"])
    n = round(1.0 / engine.h)
    result = engine.run(n)
    tail = result.t >= 0.7
    assert np.max(np.abs(result["table.s"][tail])) < 1e-6
    return float(np.mean(result["motor.i_q"][tail]))


def test_vertical_axis_holds_its_weight_minus_the_counterbalance(tmp_path):
    # at rest the screw passes F r c to the motor, c = (1/eta + eta)/2 (plant.ball_screw):
    # i_q = (m g - f_cb) r c / K_t, K_t = 1.5 p psi_pm
    r = 0.01 / (2 * math.pi)
    c = 0.5 * (1 / 0.9 + 0.9)
    k_t = 1.5 * 4 * 0.3167
    weight = 202.0 * 9.80665
    expected = (weight - 1500.0) * r * c / k_t
    assert holding_current(MACHINE) == pytest.approx(expected, rel=0.01)
    # a gas spring instead: f = f_N - k (s - s_0) = 1500 + 600 * 0.25 N at s = 0
    data = yaml.safe_load(MACHINE.read_text())
    data["axes"]["Z"]["vertical"]["counterbalance"] = {
        "type": "gas_spring", "f_N": 1500.0, "s_0_m": 0.25, "k_N_m": 600.0
    }  # fmt: skip
    path = write_machine(tmp_path, axes=data["axes"])
    expected = (weight - 1650.0) * r * c / k_t
    assert holding_current(path) == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"Q": {"include": "axis_default.yaml"}},
            r"machine.yaml: axes.Q: the NC has no axis Q \(nc.axes: X, Y, Z, B\)",
        ),
        (
            {"B": {"include": "axis_default.yaml"}},
            r"machine.yaml: axes.B: B is a rotary axis; only linear axes have a plant",
        ),
        (
            {"X": {"include": "nowhere.yaml"}},
            r"machine.yaml: axes.X.include: .*nowhere.yaml: no such config file",
        ),
        ({"X": {"inlcude": "axis_default.yaml"}}, r"axes.X: unknown key\(s\) inlcude; allowed"),
        (
            {
                "X": {
                    "include": "axis_default.yaml",
                    "vertical": {"flange": "slide.flange", "m_kg": 9.0},
                }
            },
            r"axes.X.vertical.flange = 'slide.flange': the plant has no component slide",
        ),
        (
            {
                "X": {
                    "include": "axis_default.yaml",
                    "vertical": {"flange": "table.flange", "m_kg": -1.0},
                }
            },
            r"machine.yaml: axes.X.vertical.m_kg = -1.0: must be > 0",
        ),
        (
            {
                "X": {
                    "include": "axis_default.yaml",
                    "vertical": {
                        "flange": "table.flange",
                        "m_kg": 9.0,
                        "counterbalance": {"type": "constant_force", "f_N": 5.0, "k_N_m": 3.0},
                    },
                }
            },
            r"vertical.counterbalance.s_0_m, k_N_m = 0.0, 3.0: only a gas_spring has them",
        ),
    ],
)
def test_machine_config_errors_are_one_line(tmp_path, change, message):
    data = yaml.safe_load(MACHINE.read_text())
    path = write_machine(tmp_path, axes={**data["axes"], **change})
    with pytest.raises(ConfigError, match=message) as info:
        load_machine_config(path)
    assert "\n" not in str(info.value)


def test_missing_sections_and_unknown_axes_selection(tmp_path):
    with pytest.raises(ConfigError, match=r"machine.yaml: missing required section nc"):
        load_machine_config(write_machine(tmp_path, nc=None))
    with pytest.raises(ConfigError, match=r"unknown section\(s\) plant; allowed: machine, nc"):
        load_machine_config(write_machine(tmp_path, plant={}))
    with pytest.raises(ConfigError, match=r"\(s\) controller; allowed: machine, nc, axes, ros"):
        load_machine_config(write_machine(tmp_path, controller={}))
    machine = load_machine_config(MACHINE)
    with pytest.raises(ConfigError, match=r"--axes X,B: axis B has no plant \(simulated axes"):
        machine.select(["X", "B"])


def test_program_axis_the_machine_lacks_is_refused_before_anything_moves():
    machine = load_machine_config(MACHINE)
    assert validate_program("G1 B0\nG1 X10 B30 F1000\n", machine.nc) == 1
    with pytest.raises(GcodeError, match=r"<text>:1:7: word 'A5': unknown word \(axis A is not"):
        validate_program("G1 X1 A5 F100\n", machine.nc)
