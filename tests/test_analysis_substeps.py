"""The twin's RK4 sub-steps: chosen for the springs' oscillations as well as the damping slopes,
and never fewer than the model's own engine.substeps."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from feed_twin.analysis.twin import Drive, ModelDoc, Twin
from feed_twin.core.config import ConfigError
from feed_twin.sim.engine import RK4_STABILITY_MARGIN

ROOT = Path(__file__).resolve().parents[1]
TRUTH_NOMINAL = ROOT / "config" / "truth_nominal.yaml"
J_ROTOR, J_SCREW, K_COUPLING = 6.0e-4, 4.0e-4, 1.2e4  # the truth machine's data sheet


def _with_coupling(engine: dict | None = None) -> ModelDoc:
    """The truth machine's nominal twin (its bellows coupling between rotor and screw, not
    lumped into one inertia) with its loops at a 1 ms tick."""
    doc = ModelDoc.load(TRUTH_NOMINAL)
    assert doc.component("coupling")["params"]["k"] == K_COUPLING
    assert doc.component("motor")["params"]["J"] == J_ROTOR
    assert doc.component("screw_j")["params"]["J"] == J_SCREW
    data = copy.deepcopy(doc.data)
    ctrl = data["controller"]
    ctrl["base_period_s"] = ctrl["position"]["period_s"] = ctrl["velocity"]["period_s"] = 1e-3
    if engine is not None:
        data["engine"] = engine
    return ModelDoc(data=data, source="<truth with coupling>")


@pytest.mark.slow  # a kernel of its own (about 1 min to compile, more on a loaded host)
def test_a_stiff_coupling_at_a_1_khz_tick_gets_the_sub_steps_its_mode_needs():
    """The coupling's torsion mode, rotor against screw + table reflected through the lead
    (150 kg (lead / 2 pi)^2 = 3.8e-4 kg m^2): omega = sqrt(k (1/J_r + 1/J_s)) = 5.9e3 rad/s,
    h omega = 5.9 at 1 ms, beyond RK4's stability. The damping alone allowed one sub-step, and
    the nominal loop diverged; now 4 (h omega / 4 = 1.5 < 2.5), and it settles."""
    twin = Twin.compile(_with_coupling())
    m_table = twin.doc.component("table")["params"]["m"]
    j_load = J_SCREW + m_table * (0.01 / (2.0 * math.pi)) ** 2
    omega = math.sqrt(K_COUPLING * (1.0 / J_ROTOR + 1.0 / j_load))
    h = twin.base_period_s
    assert h * omega > RK4_STABILITY_MARGIN  # one sub-step would not do
    assert twin.engine.nsub == 4
    assert h / twin.engine.nsub * omega < RK4_STABILITY_MARGIN
    assert 0.0 < twin.settle_time_s() < 1.0  # the nominal loop runs and settles
    t = h * np.arange(300)
    out = twin.simulate(Drive.at_rest(t, x0_m=1e-4), twin.nominal[None, :])
    assert out.ok[0] and np.all(np.isfinite(out.x_m[0]))


def test_the_models_own_substeps_are_kept_and_checked():
    assert Twin.compile(_with_coupling({"substeps": 16})).engine.nsub == 16
    with pytest.raises(ConfigError, match=r"engine.substeps = 0: must be a whole number >= 1"):
        Twin.compile(_with_coupling({"substeps": 0}))
