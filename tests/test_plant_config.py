"""Bad plant and axis configurations fail with the file, the field and the value."""

from __future__ import annotations

import copy
import math

import pytest

from feed_twin.core.config import ConfigError, load_yaml
from feed_twin.sim.config import load_axis_config

SOURCE = "config/emps.yaml"


@pytest.fixture(scope="module")
def emps_raw() -> dict:
    return load_yaml(SOURCE)


def _component(data: dict, name: str) -> dict:
    return next(c for c in data["plant"]["components"] if c["name"] == name)


def _load(data: dict):
    return load_axis_config(data, source=SOURCE)


@pytest.mark.parametrize(
    ("name", "field", "value", "message"),
    [
        ("table", "m", -95.0, "config/emps.yaml: plant.table.m = -95.0: must be > 0"),
        ("screw", "lead", 0.0, "config/emps.yaml: plant.screw.lead = 0.0: must be > 0"),
        (
            "screw",
            "efficiency",
            1.2,
            r"config/emps.yaml: plant.screw.efficiency = 1.2: must lie in \[0.001, 1.0\]",
        ),
        ("friction", "v_reg", 0.0, "config/emps.yaml: plant.friction.v_reg = 0.0: must be > 0"),
        (
            "friction",
            "F_c_pos",
            "a lot",
            "config/emps.yaml: plant.friction.F_c_pos = 'a lot': expected a number",
        ),
        (
            "encoder",
            "delay_ticks",
            64,
            r"config/emps.yaml: plant.encoder.delay_ticks = 64.0: must lie in \[0, 63\]",
        ),
        (
            "encoder",
            "delay_ticks",
            63.25,  # a fraction of a tick reads the sample 64 ticks back: beyond the ring
            r"config/emps.yaml: plant.encoder.delay_ticks = 63.25: must lie in \[0, 63\]",
        ),
        (
            "encoder",
            "delay_ticks",
            -0.5,
            r"config/emps.yaml: plant.encoder.delay_ticks = -0.5: must lie in \[0, 63\]",
        ),
        (
            "encoder",
            "delay_ticks",
            math.nan,
            r"config/emps.yaml: plant.encoder.delay_ticks = nan: must lie in \[0, 63\]",
        ),
        (
            "drive",
            "domain",
            "linear",
            "config/emps.yaml: plant.drive.domain = 'linear': must be one of 'rotational', "
            "'translational'",
        ),
    ],
)
def test_non_physical_parameters_name_file_field_and_value(emps_raw, name, field, value, message):
    data = copy.deepcopy(emps_raw)
    _component(data, name)["params"][field] = value
    with pytest.raises(ConfigError, match=f"^{message}$"):
        _load(data)


def test_negative_backlash_gap_is_refused():
    data = load_yaml("config/axis_default.yaml")
    _component(data, "backlash")["params"]["gap"] = -1e-6
    with pytest.raises(
        ConfigError,
        match=r"^config/axis_default.yaml: plant.backlash.gap = -1e-06: must be >= 0$",
    ):
        load_axis_config(data, source="config/axis_default.yaml")


def test_unknown_and_missing_keys(emps_raw):
    data = copy.deepcopy(emps_raw)
    _component(data, "table")["params"]["mass"] = 3.0
    with pytest.raises(
        ConfigError, match=r"^config/emps.yaml: plant.table: unknown key\(s\) mass; allowed: m$"
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    del _component(data, "screw")["params"]["lead"]
    with pytest.raises(
        ConfigError, match=r"^config/emps.yaml: plant.screw: missing required field\(s\) lead$"
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["components"][0]["colour"] = "red"
    with pytest.raises(
        ConfigError,
        match=r"^config/emps.yaml: plant.components\[0\]: unknown key\(s\) colour; allowed: name, "
        "type, params$",
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["wires"] = []
    with pytest.raises(ConfigError, match=r"plant: unknown key\(s\) wires; allowed: components"):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plnat"] = {}
    with pytest.raises(
        ConfigError, match=r"^config/emps.yaml: unknown section\(s\) plnat; allowed"
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    del data["engine"]
    with pytest.raises(ConfigError, match="^config/emps.yaml: missing required section engine$"):
        _load(data)


def test_unknown_type_and_bad_connections(emps_raw):
    data = copy.deepcopy(emps_raw)
    _component(data, "table")["type"] = "Table"
    with pytest.raises(
        ConfigError,
        match=r"^config/emps.yaml: plant.table.type = 'Table': unknown component type; known: ",
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["connect"].append(["table.flange", "motor.flange"])
    with pytest.raises(
        ConfigError,
        match=r"plant.connect\[6\] = 'motor.flange': no component named 'motor'",
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["connect"].append(["table.shaft", "friction.flange"])
    with pytest.raises(ConfigError, match=r"Mass\) has no port 'shaft'; ports: flange"):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["connect"].append(["screw.rot", "friction.flange"])
    with pytest.raises(
        ConfigError, match="cannot connect a rotational port to a translational port"
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["plant"]["connect"].append(["table.flange"])
    with pytest.raises(ConfigError, match=r"plant.connect\[6\] = \['table.flange'\]: expected"):
        _load(data)


def test_a_massless_flange_is_refused(emps_raw):
    data = copy.deepcopy(emps_raw)
    data["plant"]["connect"].remove(["table.flange", "friction.flange"])
    with pytest.raises(
        ConfigError,
        match=r"^config/emps.yaml: plant.connect: the flanges friction.flange carry no inertia "
        r"\(massless node\)",
    ):
        _load(data)


def test_engine_rates_must_be_integer_multiples(emps_raw):
    data = copy.deepcopy(emps_raw)
    data["engine"]["output_period_s"] = 1.5e-3
    with pytest.raises(
        ConfigError,
        match=r"^config/emps.yaml: engine.output_period_s = 0.0015: must be an integer multiple "
        r"of base_period_s = 0.001$",
    ):
        _load(data)
    data = copy.deepcopy(emps_raw)
    data["engine"]["base_period_s"] = 5e-4
    with pytest.raises(
        ConfigError,
        match=r"engine.base_period_s = 0.0005: must equal controller.base_period_s = 0.001",
    ):
        _load(data)


def test_a_lossy_screw_needs_a_compliance_before_the_mass():
    data = load_yaml(SOURCE)
    _component(data, "screw")["params"]["efficiency"] = 0.9
    with pytest.raises(
        ConfigError,
        match=r"plant.screw.efficiency = 0.9: a lossy screw needs a massless translational flange",
    ):
        _load(data)
