"""When the drive-stage twin's effort is stamped (analysis.drive_stage): its effort is the
motor's actual q-current, a state, recorded as it stands at its stamp, not shifted one tick as
a command is (twin.acted). Checked against the same engine's own record of that current, and
against the current loop's first answer to a step of its setpoint."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.drive_stage import drive_stage, expand
from feed_twin.analysis.model_doc import ModelDoc
from feed_twin.analysis.twin import Drive, Twin

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "config" / "truth_nominal.yaml"
STEP_TICK = 80  # the base tick at which the known effort steps
STEP_NM = 0.9  # [N m] 2 A at K_t 0.45: far above the stage's smallest current


def _step_drive(t_s: np.ndarray) -> Drive:
    """At rest, a known effort stepping at STEP_TICK (added to the velocity loop's)."""
    step = np.where(np.arange(len(t_s)) >= STEP_TICK, STEP_NM, 0.0)
    return dataclasses.replace(Drive.at_rest(t_s), effort_add=step)


@pytest.mark.slow
def test_the_drive_stage_records_its_current_at_its_stamp() -> None:
    """The expanded twin on a record at its own 0.125 ms tick. (1) Two paths: its effort is the
    engine's own record of the motor's i_q times K_t at the same ticks, exactly. (2) Physics:
    the setpoint steps at tick k; the loop's voltage applies one sample late (computation
    delay), so the current is untouched up to stamp k + 1 and has moved at k + 2, by the PI's
    first voltage u = Kp (1 + h / Ti) di_ref on the R-L winding over one period,
    (u / R) (1 - exp(-R h / L)) (the integral part's discretisation aside, h / Ti = 3 %).
    A current shifted as a command would move first at k + 3. Slow: it compiles the
    expanded twin's kernel (shared with tests/test_analysis_drive_stage.py)."""
    from feed_twin.core import signals
    from feed_twin.sim.batch import run_batch
    from feed_twin.sim.program import set_nc_reference

    doc = ModelDoc.load(NOMINAL)
    stage = drive_stage(doc)
    assert stage is not None
    twin = Twin.compile(expand(doc))
    assert twin.effort_is_current
    h = twin.base_period_s
    assert h == stage.current_period_s
    t = h * np.arange(200)
    drive = _step_drive(t)
    p = twin.nominal[None, :]
    out = twin.simulate(drive, p)
    assert out.ok.all() and out.effort is not None
    effort = out.effort[0]

    k_t = doc.reference_gain
    assert k_t is not None
    ref = np.zeros((len(t), signals.REF_SIZE))
    set_nc_reference(ref, drive.pos_ref_m, drive.vel_ref_m_s, drive.acc_ref_m_s2)
    assert drive.effort_add is not None
    ref[:, signals.REF_EFFORT_ADD] = drive.effort_add / k_t
    res = run_batch(twin.engine, p, len(t), ref=ref, x0=twin.initial_state(0.0, p[0]))
    motor = twin.stage_motor
    np.testing.assert_array_equal(effort, res[f"{motor}.i_q"][0] * k_t)

    i_q = effort / k_t
    di_ref = STEP_NM / k_t
    before = i_q[STEP_TICK - 1]
    assert abs(before) < 1e-3 * di_ref  # at rest: the loop holds no current
    assert i_q[STEP_TICK + 1] == pytest.approx(before, abs=1e-6 * di_ref)
    R, L = stage.R_s_ohm, stage.L_H
    u = stage.Kp_V_A * di_ref
    first = (u / R) * (1.0 - math.exp(-R * h / L))
    assert i_q[STEP_TICK + 2] - before == pytest.approx(first, rel=1.5 * h / stage.Ti_s)
