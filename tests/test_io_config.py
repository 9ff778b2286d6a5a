"""The typed YAML loader: conversion, and every error path names file, field and value."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import pytest

from feed_twin.core.config import ConfigError, from_mapping, load_yaml
from feed_twin.core.validate import require_integer_multiple, require_positive


@dataclass(frozen=True, kw_only=True)
class _Bearing:
    k: float  # axial stiffness [N/m]

    def __post_init__(self) -> None:
        require_positive("k", self.k)


@dataclass(frozen=True, kw_only=True)
class _Axis:
    m: float  # table mass [kg]
    arrangement: Literal["fixed_fixed", "fixed_free"]
    bearings: tuple[_Bearing, ...]
    counts: int = 4096  # encoder counts per revolution

    def __post_init__(self) -> None:
        require_positive("m", self.m)


def test_nested_mapping_converts_to_frozen_dataclasses():
    axis = from_mapping(
        _Axis,
        {"m": 150, "arrangement": "fixed_fixed", "bearings": [{"k": 1e9}, {"k": 2e9}]},
        source="axis.yaml",
        path="plant",
    )
    assert axis.m == 150.0 and isinstance(axis.m, float)
    assert axis.bearings[1].k == 2e9
    assert axis.counts == 4096


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (
            {"m": -3.0, "arrangement": "fixed_free", "bearings": []},
            "axis.yaml: plant.m = -3.0: must be > 0",
        ),
        (
            {"m": 1.0, "arrangement": "fixed_free", "bearings": [{"k": 0}]},
            "axis.yaml: plant.bearings[0].k = 0.0: must be > 0",
        ),
        (
            {"m": 1.0, "arrangement": "fixed_free", "bearings": [], "mass": 2},
            "axis.yaml: plant: unknown key(s) mass; allowed: m, arrangement, bearings, counts",
        ),
        (
            {"arrangement": "fixed_free", "bearings": []},
            "axis.yaml: plant: missing required field(s) m",
        ),
        (
            {"m": "heavy", "arrangement": "fixed_free", "bearings": []},
            "axis.yaml: plant.m = 'heavy': expected a number",
        ),
        (
            {"m": 1.0, "arrangement": "floating", "bearings": []},
            "axis.yaml: plant.arrangement = 'floating': must be one of 'fixed_fixed', 'fixed_free'",
        ),
        (
            {"m": 1.0, "arrangement": "fixed_free", "bearings": [], "counts": 1.5},
            "axis.yaml: plant.counts = 1.5: expected a whole number",
        ),
    ],
)
def test_errors_name_file_field_and_value(data, message):
    with pytest.raises(ConfigError) as excinfo:
        from_mapping(_Axis, data, source="axis.yaml", path="plant")
    assert str(excinfo.value) == message


def test_integer_multiple_accepts_exact_ratio_and_rejects_others():
    assert require_integer_multiple("velocity_period_s", 125e-6, 62.5e-6, "base_period_s") == 2
    with pytest.raises(ValueError, match=r"velocity_period_s = 0\.0001: must be an integer"):
        require_integer_multiple("velocity_period_s", 100e-6, 62.5e-6, "base_period_s")


def test_load_yaml_reports_file_and_line_of_syntax_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("plant:\n  m: [1, 2\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.yaml:3:1: invalid YAML"):
        load_yaml(bad)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "the file is empty"),
        (b"- 1\n- 2\n", "the top level must be a mapping, not list"),
        (b"\xff\xfe\x00binary", "not a text file"),
    ],
)
def test_load_yaml_rejects_empty_list_and_binary_files(tmp_path, content, message):
    path = tmp_path / "c.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError, match=message):
        load_yaml(path)


def test_load_yaml_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.yaml: no such config file"):
        load_yaml(tmp_path / "nope.yaml")
