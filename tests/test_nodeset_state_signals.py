"""AxisState fields come from what components declare (STATE_OUTPUTS), not from their names."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from feed_twin.nodeset.config import StateSignals
from feed_twin.sim.config import build_engine, load_axis_config

AXIS = Path(__file__).resolve().parents[1] / "config" / "axis_default.yaml"


def resolved(text: str) -> StateSignals:
    axis = load_axis_config(yaml.safe_load(text), source="test axis")
    return StateSignals().resolve(axis.plant, build_engine(axis).all_names)


def test_the_default_axis_reports_its_motor_bus_friction_and_screw() -> None:
    got = resolved(AXIS.read_text())
    assert got.i_q == "motor.i_q" and got.torque_em == "motor.tau_e"
    assert got.motor_angle == "motor.phi" and got.u_dc == "bus.u_dc"
    assert got.friction_force == "-guides.force"  # the table receives -F(v)
    assert got.screw_force == "backlash.force"
    assert got.table_position == "table.s"


def test_renamed_components_are_still_found() -> None:
    text = re.sub(r"\bguides\b", "rails", AXIS.read_text())
    text = re.sub(r"\bbacklash\b", "play", text)
    text = re.sub(r"\bmotor\b", "spindle_motor", text)
    got = resolved(text)
    assert got.friction_force == "-rails.force"
    assert got.screw_force == "play.force"
    assert got.i_q == "spindle_motor.i_q" and got.motor_velocity == "spindle_motor.omega"


def test_a_plant_without_the_component_reports_nothing_for_it() -> None:
    # EMPS: one body driven by a force source, no motor, bus or backlash
    axis = load_axis_config(AXIS.parent / "emps.yaml")
    got = StateSignals().resolve(axis.plant, build_engine(axis).all_names)
    assert got.i_q == "" and got.u_dc == "" and got.screw_force == ""
    assert got.friction_force == "-friction.force"
    assert set(got.names()) == {"table.s", "table.v", "friction.force"}


def test_explicit_names_win_and_two_candidates_are_refused() -> None:
    text = AXIS.read_text().replace(
        "    - {name: cutting, type: ExternalForce, params: {}}",
        "    - {name: wipers, type: GuideFriction, params: {F_c_pos: 5.0, F_c_neg: 5.0, "
        "F_v_pos: 0.0, F_v_neg: 0.0, dF_s: 0.0, v_s: 2.0e-3, v_reg: 1.0e-4}}\n"
        "    - {name: cutting, type: ExternalForce, params: {}}",
    )
    text = text.replace(
        "    - [table.flange, guides.flange]",
        "    - [table.flange, guides.flange]\n    - [table.flange, wipers.flange]",
    )
    axis = load_axis_config(yaml.safe_load(text), source="test axis")
    known = build_engine(axis).all_names
    with pytest.raises(ValueError, match=r"ros.signals.friction_force: -guides.force, "):
        StateSignals().resolve(axis.plant, known)
    chosen = StateSignals(friction_force="-guides.force").resolve(axis.plant, known)
    assert chosen.friction_force == "-guides.force"
