"""When the twin's effort is stamped: a drive's actual current (force) sampled at tick k is the
effort that acted over the tick before k, the command of k - 1; a recorded setpoint is the
command issued at k (column map `effort_sample`). A drive that follows its command later than
the twin (its setpoint latency) answers later: the command delay shifts every output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.model_doc import COMMAND_DELAY_SLOT
from feed_twin.analysis.twin import Drive, ModelDoc, Twin
from feed_twin.core.config import ConfigError
from feed_twin.io.column_map import load_column_map

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "emps_nominal.yaml"


def _free_mass_twin() -> tuple[Twin, float]:
    """The EMPS twin without its viscous friction: a free mass behind an effort source."""
    doc = ModelDoc.load(NOMINAL)
    for side in ("F_v_pos", "F_v_neg"):
        doc = doc.set_raw("friction", side, 0.0)
    return Twin.compile(doc), float(doc.component("table")["params"]["m"])


def _step_drive(effort_actual: bool) -> Drive:
    h = 1e-3
    t = h * np.arange(200)
    x_ref = np.where(t >= 0.05, 1e-3, 0.0)  # a 1 mm position step at 50 ms
    return Drive(
        t_s=t,
        pos_ref_m=x_ref,
        vel_ref_m_s=np.zeros_like(t),
        acc_ref_m_s2=np.zeros_like(t),
        effort_add=None,
        force_ext_N=None,
        x0_m=0.0,
        sensor="motor_encoder",
        effort_actual=effort_actual,
    )


def test_an_actual_effort_is_the_force_that_moved_the_mass_before_its_stamp():
    """A free mass m under a force held over each tick (F_j on (j h, (j + 1) h]) moves exactly
    as x[k+1] - 2 x[k] + x[k-1] = h^2 / (2 m) (F_(k-1) + F_k). The effort the twin reports as a
    drive's actual value at k is F_(k-1): the second difference at k is h^2/(2m) times the sum
    of the actual efforts at k and k + 1. The setpoint stamp (the command issued at k, F_k)
    fits the same motion only one tick earlier, and not the actual stamp's relation: the
    closed loop's force swings between its limits (+-352 N) after the step."""
    twin, m = _free_mass_twin()
    h = twin.base_period_s
    actual = twin.simulate(_step_drive(True), twin.nominal[None, :])
    setpoint = twin.simulate(_step_drive(False), twin.nominal[None, :])
    x = actual.x_m[0]
    assert actual.effort is not None and setpoint.effort is not None
    a, s = actual.effort[0], setpoint.effort[0]
    np.testing.assert_array_equal(x, setpoint.x_m[0])  # the stamp changes no motion
    second = (x[2:] - 2.0 * x[1:-1] + x[:-2]) * 2.0 * m / h**2  # [N] F_(k-1) + F_k, k = 1..
    scale = np.abs(second).max()
    assert scale > 500.0  # the step drives the mass hard: the test can tell the stamps apart
    np.testing.assert_allclose(second, a[1:-1] + a[2:], atol=1e-6 * scale)
    np.testing.assert_allclose(second, s[:-2] + s[1:-1], atol=1e-6 * scale)
    assert np.abs(second - (s[1:-1] + s[2:])).max() > 0.1 * scale


def test_the_column_map_says_what_the_effort_column_holds(tmp_path):
    base = (
        "time: {column: t, unit: s}\nposition_sensor: motor_encoder\n"
        "signals:\n  pos_meas_m: {column: x, unit: m}\n  force_cmd_N: {column: f, unit: N}\n"
        "plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}\n"
    )
    path = tmp_path / "map.yaml"
    path.write_text(base)
    assert load_column_map(path).effort_sample == "actual"  # a drive's trace: its actual value
    path.write_text(base + "effort_sample: setpoint\n")
    assert load_column_map(path).effort_sample == "setpoint"
    assert load_column_map(ROOT / "config" / "emps_map.yaml").effort_sample == "setpoint"
    path.write_text(base + "effort_sample: measured\n")
    with pytest.raises(ConfigError, match="effort_sample = 'measured'"):
        load_column_map(path)


def _move_drive(delay_ticks: int) -> Drive:
    """A smooth 20 mm move (cosine velocity profile), its command `delay_ticks` ticks late."""
    h = 1e-3
    t = h * np.arange(600)
    s = np.clip((t - 0.05 - h * delay_ticks) / 0.3, 0.0, 1.0)
    x = 0.02 * (s - np.sin(2.0 * np.pi * s) / (2.0 * np.pi))
    v = np.gradient(x, h)
    return Drive(
        t_s=t,
        pos_ref_m=x,
        vel_ref_m_s=v,
        acc_ref_m_s2=np.gradient(v, h),
        effort_add=None,
        force_ext_N=None,
        x0_m=0.0,
        sensor="motor_encoder",
    )


def test_a_command_delay_is_the_answer_to_a_later_command():
    """The twin is time invariant: following its command 3 ms later gives its answer 3 ms
    later. The command-delay slot (the drive's setpoint latency against the twin's loops)
    shifts the outputs of one run; it equals the run on the command given 3 ms later, sample
    for sample, position and effort."""
    twin = Twin.compile(ModelDoc.load(NOMINAL))
    p = twin.nominal[None, :]
    late = twin.simulate(_move_drive(3), p)
    shifted = twin.simulate(_move_drive(0), p, record=[{COMMAND_DELAY_SLOT: 3e-3}])
    assert late.effort is not None and shifted.effort is not None
    assert np.abs(late.effort[0]).max() > 10.0  # the move needs force: the test can fail
    np.testing.assert_allclose(shifted.x_m[0][3:], late.x_m[0][3:], atol=1e-12)
    scale = np.abs(late.effort[0]).max()  # [N], rounding only: 1e-11 of it was seen
    np.testing.assert_allclose(shifted.effort[0][3:], late.effort[0][3:], atol=1e-9 * scale)
