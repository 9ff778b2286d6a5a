"""Sensor delays of a fraction of a tick: the ring read by linear interpolation between the two
neighbouring samples (feed_twin.plant.sensors.delay_taps), in the numba and the C kernel, and
identified between whole ticks (analysis.trials.refined).

A delay d = n + f ticks (period h) reads y_k = x_{k-n} + f (x_{k-n-1} - x_{k-n}). For a ramp that
is the ramp d h late, exactly. For a sampled sinusoid x_k = Re(c z^k), z = e^{j w h}, it is
Re(G c z^k) with G = z^-n (1 - f + f/z): the lag w d h of a true delay, to within the phase error
arg(1 - f + f e^{-j w h}) + f w h of the first-order hold (zero at f = 0 and 1/2, third order in
w h), and the gain |1 - f + f e^{-j w h}| <= 1.
"""

from __future__ import annotations

import cmath
import math
from pathlib import Path

import numpy as np
import pytest
from twin_support import strong_candidate

from feed_twin.core import signals as sig
from feed_twin.plant.config import load_plant
from feed_twin.plant.sensors import delay_taps
from feed_twin.sim.engine import Engine

ROOT = Path(__file__).resolve().parents[1]
H = 1e-3  # [s] base period
COUNTS = 2**40  # encoder counts per revolution: 5.7e-12 rad, no quantisation to speak of
STEP = 2.0 * math.pi / COUNTS
J_ROTOR, J_GROUND = 1e-4, 10.0  # [kg m^2]


def _rotor_engine(delay: float, *, spring: bool) -> Engine:
    """An inertia with an encoder `delay` ticks late; with `spring`, tied by an undamped
    coupling to an inertia 1e5 times heavier (an oscillator at 50 Hz), else free."""
    components = [
        {"name": "rotor", "type": "Inertia", "params": {"J": J_ROTOR}},
        {
            "name": "encoder",
            "type": "Encoder",
            "params": {"counts_per_rev": COUNTS, "delay_ticks": delay},
        },
    ]
    connect = [["rotor.flange", "encoder.flange"]]
    if spring:
        k = J_ROTOR * (2.0 * math.pi * 50.0) ** 2
        components += [
            {"name": "ground", "type": "Inertia", "params": {"J": J_GROUND}},
            {"name": "coupling", "type": "Coupling", "params": {"k": k, "d": 0.0}},
        ]
        connect += [["rotor.flange", "coupling.a"], ["coupling.b", "ground.flange"]]
    else:
        components.append(
            {
                "name": "drive",
                "type": "EffortSource",
                "params": {"domain": "rotational", "gain": 1.0, "T_lag": 0.0, "f_max": 1e6},
            }
        )
        connect.append(["rotor.flange", "drive.flange"])
    plant = load_plant({"components": components, "connect": connect}, source="rotor")
    return Engine(plant, base_period_s=H, record=["rotor.phi", "meas.theta_enc_rad"])


def _run(engine: Engine, n: int, **start: float) -> tuple[np.ndarray, np.ndarray]:
    x0 = np.zeros(len(engine.model.state_names))
    for name, value in start.items():
        x0[engine.model.state_index[name]] = value
    engine.reset(x0=x0)
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_ENABLED] = 1.0
    res = engine.advance(n, drive=drive)
    return res["rotor.phi"], res["meas.theta_enc_rad"]


@pytest.mark.parametrize("delay", [0.5, 2.25, 7.75, 62.875])
def test_a_ramp_is_delayed_exactly(delay):
    omega = 3.0  # [rad/s] a free inertia: phi = omega t, exactly under RK4
    phi, meas = _run(_rotor_engine(delay, spring=False), 200, **{"rotor.omega": omega})
    t = H * np.arange(len(phi))
    np.testing.assert_allclose(phi, omega * t, rtol=1e-12, atol=1e-15)
    late = t >= (math.floor(delay) + 1) * H  # before, the first sample is held
    assert late.sum() > 100
    np.testing.assert_allclose(meas[late], omega * (t[late] - delay * H), rtol=0, atol=2 * STEP)
    # the same from numpy's interpolation of the recorded angle (the first sample held before)
    np.testing.assert_allclose(meas, np.interp(t - delay * H, t, phi), rtol=0, atol=2 * STEP)


def _discrete_pole(x: np.ndarray) -> complex:
    """z of x_k = Re(c z^k) (RK4's own frequency and damping per tick) by linear prediction:
    x_{k+1} = 2 Re(z) x_k - |z|^2 x_{k-1}, least squares."""
    a = np.column_stack([x[1:-1], -x[:-2]])
    (two_re, abs2), *_ = np.linalg.lstsq(a, x[2:], rcond=None)
    re = two_re / 2.0
    return complex(re, math.sqrt(abs2 - re * re))


def _phasor(x: np.ndarray, z: complex, k: np.ndarray) -> complex:
    """c of x_k = Re(c z^k) by least squares."""
    zk = z**k
    (a, b), *_ = np.linalg.lstsq(np.column_stack([zk.real, -zk.imag]), x, rcond=None)
    return complex(a, b)


@pytest.mark.parametrize("delay", [2.0, 2.25, 2.5, 2.75])
def test_a_sine_lags_by_the_delay_within_the_holds_closed_form_error(delay):
    n_ticks = 400
    phi0 = 1e-2
    phi, meas = _run(_rotor_engine(delay, spring=True), n_ticks, **{"rotor.phi": phi0})
    # at rest, the two inertias' common angle stays where it began (RK4 keeps linear invariants)
    rest = J_ROTOR * phi0 / (J_ROTOR + J_GROUND)
    phi, meas = phi - rest, meas - rest
    k = np.arange(n_ticks)
    z = _discrete_pole(phi)
    theta = cmath.phase(z)  # w h: 50 Hz at 1 kHz, RK4's frequency
    assert theta == pytest.approx(2.0 * math.pi * 50.0 * H, rel=1e-3)
    late = k > math.floor(delay) + 1
    gain = _phasor(meas[late], z, k[late]) / _phasor(phi, z, k)
    n, f = math.floor(delay), delay - math.floor(delay)
    # the interpolation law on the simulated sinusoid (RK4 damps it by 1 - |z| a tick)
    assert abs(gain - z**-n * (1.0 - f + f / z)) < 1e-9
    damping = 1.0 - abs(z)
    assert 0.0 <= damping < 1e-5
    # the lag of a true delay, w d h, within the first-order hold's phase error e (zero at
    # f = 0 and 1/2), and its gain: closed forms on the unit circle
    hold = 1.0 - f + f * cmath.exp(-1j * theta)
    e = cmath.phase(hold) + f * theta
    assert -cmath.phase(gain) == pytest.approx(theta * delay - e, abs=2 * delay * damping)
    assert abs(e) <= 1.01 * f * (1 - f) * abs(1 - 2 * f) * theta**3 / 6 + 1e-15
    assert abs(gain) == pytest.approx(abs(hold), abs=2 * delay * damping)
    assert 1.0 - abs(hold) == pytest.approx(f * (1 - f) * theta**2 / 2, rel=0.01, abs=1e-15)


def test_delay_taps_read_the_neighbouring_samples_and_hold_the_first():
    assert delay_taps(2.25, 10) == (8, 7, 0.25)
    assert delay_taps(3.0, 10) == (7, 6, 0.0)
    assert delay_taps(2.25, 2) == (0, 0, 0.25)  # the older sample is before tick 0
    assert delay_taps(62.5, 130) == ((130 - 62) % 64, (130 - 63) % 64, 0.5)


def test_a_fractional_delay_in_the_c_kernel_gives_the_numba_kernels_doubles():
    """EMPS driven open loop (the kernel of tests/test_native_kernel.py's open-loop test, built
    once), its encoder 2.75 ticks late: a parameter, set in both kernels."""
    from feed_twin.native.build import CModel, c_kernel_for_axis, compile_kernel
    from feed_twin.sim.config import build_engine, load_axis_config

    axis = load_axis_config(ROOT / "config" / "emps.yaml")
    n = 3000
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_ENABLED] = 1.0
    drive[:, sig.OUT_EFFORT_CMD] = 2.0 * np.sin(np.arange(n) * 2e-3)
    params = axis.plant.param_vector({"encoder.delay_ticks": 2.75})
    engine = build_engine(
        axis, closed_loop=False, params=params, output_period_s=axis.engine.base_period_s
    )
    expected = engine.run(n, drive=drive)
    kernel = c_kernel_for_axis(axis, closed_loop=False)
    model = CModel(compile_kernel(kernel), kernel)
    model.set_param("encoder.delay_ticks", 2.75)
    got = model.run(n, drive=drive)
    assert np.array_equal(got, expected.data)
    theta = expected["meas.theta_enc_rad"]
    assert np.ptp(theta) > 1.0  # the motor turned
    # read between samples: off the encoder's count grid, and late by 2.75 ticks
    counts = theta / (2.0 * math.pi / 50000)
    assert np.any(np.abs(counts - np.round(counts)) > 0.1)
    h = axis.engine.base_period_s
    t = h * np.arange(n)
    phi = expected["table.s"] * 2.0 * math.pi / 2.5e-3  # the motor's angle: a 2.5 mm lead
    step = 2.0 * math.pi / 50000
    np.testing.assert_allclose(theta, np.interp(t - 2.75 * h, t, phi), rtol=0, atol=step)


def _truth_delay_found(tmp_path):
    """The truth machine (feed_twin.truth: its own loops, no twin code) delays the position its
    loops read by 9 of its 0.125 ms current periods, 1.125 ms: 4.5 of the twin's 0.25 ms ticks.
    Returns the grid search's result, and the likelihood's cost (fit.profile_cost) at it and at
    the two whole ticks next to it."""
    from feed_twin.analysis.channels import noise_floors, weighted_channels
    from feed_twin.analysis.effects import BY_NAME
    from feed_twin.analysis.fit import profile_cost
    from feed_twin.analysis.model_doc import ModelDoc, model_of
    from feed_twin.analysis.trials import grid_search
    from feed_twin.analysis.twin import Twin, drive_from_run
    from feed_twin.io.measured import load_measured
    from feed_twin.truth import make_record

    nominal = ModelDoc.load(ROOT / "config" / "truth_nominal.yaml")
    hidden = {"measurement_delay": {"delay_s": 1.125e-3}}
    rec = make_record(tmp_path / "run.csv", hidden=hidden, seed=5)
    run = load_measured(rec.csv, rec.map)
    edit = BY_NAME["measurement_delay"].edit(nominal, strong_candidate("measurement_delay", {}))
    twin = Twin.compile(model_of(edit.doc))
    drive = drive_from_run(run)
    out = twin.simulate(drive, twin.nominal[None, :])
    meas = weighted_channels(run, out, 1, noise_floors(run, out))
    found = grid_search(twin, edit, drive, meas)
    whole = np.repeat(twin.nominal[None, :], 2, axis=0)
    for i in twin.index["sensors.delay_ticks"]:
        whole[:, i] = (4.0, 5.0)
    ends = twin.simulate(drive, whole)
    costs = [profile_cost(meas, ends, row) for row in range(2)]
    return found, profile_cost(meas, found.outputs), costs


def test_a_delay_between_ticks_of_an_independent_machine_is_identified_between_them(tmp_path):
    """The best whole tick is refined between the two whole ticks around 4.5, and the fraction
    fits better than either of them by the channels' likelihood (fit.profile_cost: the
    refinement's measure)."""
    found, cost, whole_costs = _truth_delay_found(tmp_path)
    assert 4.0 < found.values["sensors.delay_ticks"] < 5.0
    assert "refined to" in found.message
    assert cost < min(whole_costs)


def test_a_delay_between_ticks_of_an_independent_machine_is_found_to_a_tenth_of_a_tick(tmp_path):
    found, _, _ = _truth_delay_found(tmp_path)
    assert found.values["sensors.delay_ticks"] == pytest.approx(4.5, abs=0.1)
