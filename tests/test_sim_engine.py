"""The engine: chunked runs, batch mode, sensors, seeded noise, divergence and its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.core import signals as sig
from feed_twin.plant.config import load_plant
from feed_twin.plant.sensors import MAX_DELAY_TICKS
from feed_twin.sim import batch as batch_module
from feed_twin.sim.batch import check_steps, run_batch
from feed_twin.sim.config import build_engine, load_axis_config
from feed_twin.sim.engine import DivergenceError, Engine, check_step


def _emps_ref(n: int) -> np.ndarray:
    ref = np.zeros((n, sig.REF_SIZE))
    t = np.arange(n) * 1e-3
    ref[:, sig.REF_POS_M] = 0.02 * (1.0 - np.cos(2.0 * math.pi * t))
    return ref


@pytest.fixture(scope="module")
def emps():
    return load_axis_config("config/emps.yaml")


def test_advancing_in_chunks_is_bit_identical_to_one_run(emps):
    n = 600
    ref = _emps_ref(n)
    one = build_engine(emps).run(n, ref=ref)
    engine = build_engine(emps)
    parts = []
    start = 0
    for size in (1, 7, 92, 300, 200):
        parts.append(engine.advance(size, ref=ref[start : start + size]))
        start += size
    chunks = type(one).concat(parts)
    assert np.array_equal(one.t, chunks.t)
    assert np.array_equal(one.data, chunks.data)


def test_axis_with_current_noise_is_reproducible_bit_for_bit_and_seed_dependent():
    axis = load_axis_config("config/axis_default.yaml")
    n = 400
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = 1e-4
    runs = [
        build_engine(axis, output_period_s=axis.engine.base_period_s).run(n, ref=ref) for _ in "ab"
    ]
    assert np.array_equal(runs[0].data, runs[1].data)
    engine = build_engine(axis, output_period_s=axis.engine.base_period_s)
    engine.seed = 2
    other = engine.run(n, ref=ref)
    a = runs[0]["meas.i_a_meas_A"]
    assert not np.array_equal(a, other["meas.i_a_meas_A"])
    # ADC noise: std 0.02 A around the true current, on a 100 A / 4096 step
    error = runs[0]["meas.i_a_meas_A"] - runs[0]["motor.i_a"]
    step = 100.0 / 4096
    assert np.std(error) == pytest.approx(math.sqrt(0.02**2 + step**2 / 12), rel=0.15)
    assert abs(np.mean(error)) < 0.01


def test_batch_equals_single_runs_and_flags_a_refused_set(emps):
    plant = emps.plant
    n = 300
    ref = _emps_ref(n)
    record = ["table.s", "meas.theta_enc_rad", "out.effort_cmd", "drive.effort"]
    engine = build_engine(emps, record=record)
    masses = [80.0, 95.1089, 120.0]
    P = np.array([plant.param_vector({"table.m": m}) for m in masses])
    P = np.vstack([P, plant.param_vector({"table.m": 1e-3})])  # friction far too stiff
    batch = run_batch(engine, P, n, ref=ref)
    assert list(batch.diverged) == [False, False, False, True]
    assert batch.messages[3].startswith("not run: config/emps.yaml: plant.friction: step")
    assert np.all(np.isnan(batch["table.s"][3]))
    for b, m in enumerate(masses):
        single = build_engine(emps, record=record, params=plant.param_vector({"table.m": m}))
        res = single.run(n, ref=ref)
        assert np.array_equal(batch.data[b], res.data)


def test_batch_noise_tables_shared_by_a_seed_give_the_single_runs_bits(monkeypatch):
    """Sets of one seed read one table of standard normals drawn ahead; a set alone with its
    seed, or beyond the tables' memory budget, draws its own. Either way its bits are those of
    a single run with that seed, also for a sensor whose noise is switched off."""
    axis = load_axis_config("config/axis_default.yaml")
    plant = axis.plant
    n = 160
    ref = np.zeros((n, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = 1e-4
    record = ["meas.i_a_meas_A", "meas.i_c_meas_A", "motor.i_q"]
    engine = build_engine(axis, record=record, output_period_s=axis.engine.base_period_s)
    seeds = np.array([1, 2, 2, 3, 3, 3, 3])
    P = np.tile(plant.nominal_params(), (len(seeds), 1))
    P[4, plant.param_index["current_sensor.noise_std"]] = 0.0
    plant.fill_derived(P)

    tables, table_of = batch_module._shared_normals(engine.kernel, seeds, n)
    assert tables.shape == (2, n, engine.kernel.N_NOISE)
    assert list(table_of) == [-1, 1, 1, 0, 0, 0, 0]  # the most shared seed first
    # room for one table only: seed 2's sets draw their own
    monkeypatch.setattr(batch_module, "SHARED_NORMALS_BYTES", n * engine.kernel.N_NOISE * 8)
    assert list(batch_module._shared_normals(engine.kernel, seeds, n)[1]) == [-1] * 3 + [0] * 4

    for budget in (64 * 2**20, 0):
        monkeypatch.setattr(batch_module, "SHARED_NORMALS_BYTES", budget)
        batch = run_batch(engine, P, n, ref=ref, seeds=seeds)
        for b, seed in enumerate(seeds):
            engine.p = P[b]
            engine.seed = int(seed)
            assert np.array_equal(batch.data[b], engine.run(n, ref=ref).data), (budget, b)
    quiet = batch["meas.i_a_meas_A"][4] - batch["meas.i_a_meas_A"][3]
    assert np.any(quiet != 0.0)  # the set without noise differs from its noisy twin


def test_check_steps_gives_check_step_verdict_and_message_for_every_row():
    axis = load_axis_config("config/axis_default.yaml")
    plant = axis.plant
    h = axis.engine.base_period_s
    rows = [
        {},
        {"table.m": 170.0},
        {"guides.v_reg": 1e-9},  # guide friction far too sharp for the step
        {"motor.omega_reg": 1e-9, "table.m": 170.0},  # and the motor bearing's
        {"guides.v_reg": 1e-9},
        {"table.m": 1e-6, "guides.v_reg": 2e-4},  # a vanishing table: the friction slope wins
    ]
    P = np.array([plant.param_vector(r) for r in rows])
    expected = []
    for row in P:
        try:
            check_step(plant, row, h, 1)
            expected.append("")
        except ValueError as exc:
            expected.append(str(exc))
    assert [bool(m) for m in expected] == [False, False, True, True, True, True]
    assert check_steps(plant, P, h, 1) == expected
    assert check_steps(plant, P[:0], h, 1) == []


def _unstable_axis():
    """The default axis with a backlash contact 2e4 times stiffer: far beyond RK4's reach."""
    axis = load_axis_config("config/axis_default.yaml")
    return axis.plant.with_params(axial={"k_nut": 1e13}, backlash={"k": 1e13})


def test_divergence_raises_with_time_and_state():
    plant = _unstable_axis()
    engine = Engine(plant, base_period_s=6.25e-5)
    x0 = plant.initial_state()
    x0[plant.state_index["nut.s"]] = 1e-5  # beyond the half gap: the contact engages
    engine.reset(x0=x0)
    with pytest.raises(
        DivergenceError,
        match=r"simulation diverged at t = [0-9.e-]+ s \(tick \d+\): state \w+\.(s|v|phi|omega) "
        r"of coordinate \w+ \(flanges [\w., ]+\) = [-+0-9.e]+|nan|inf, limit (10000\.0|100000\.0)$",
    ):
        engine.advance(2000)


def test_batch_flags_a_diverging_set_and_runs_the_others():
    plant = _unstable_axis()
    engine = Engine(plant, base_period_s=6.25e-5, record=["nut.s", "table.s"])
    x0 = plant.initial_state()
    x0[plant.state_index["nut.s"]] = 1e-5  # beyond the half gap: the contact engages
    stable = plant.param_vector({"axial.k_nut": 1e9, "backlash.k": 5e8})
    P = np.vstack([stable, plant.nominal_params()])
    batch = run_batch(engine, P, 400, x0=x0)
    assert list(batch.diverged) == [False, True]
    assert "simulation diverged at t = " in batch.messages[1]
    assert np.all(np.isfinite(batch["nut.s"][0]))
    assert np.isnan(batch["nut.s"][1, -1])


@pytest.mark.parametrize("delay", [3, MAX_DELAY_TICKS])
def test_encoder_quantises_and_delays_its_samples(delay):
    """Delays up to MAX_DELAY_TICKS (63: 15.75 ms at a drive's 0.25 ms tick; the ring kept
    15 before, and a 4 ms feedback delay could not be fitted)."""
    plant = load_plant(
        {
            "components": [
                {"name": "rotor", "type": "Inertia", "params": {"J": 1.0}},
                {
                    "name": "drive",
                    "type": "EffortSource",
                    "params": {"domain": "rotational", "gain": 1.0, "T_lag": 0.0, "f_max": 1e6},
                },
                {
                    "name": "encoder",
                    "type": "Encoder",
                    "params": {"counts_per_rev": 1000, "delay_ticks": delay},
                },
            ],
            "connect": [["rotor.flange", "drive.flange"], ["rotor.flange", "encoder.flange"]],
        },
        source="encoder",
    )
    engine = Engine(plant, base_period_s=1e-3, record=["rotor.phi", "meas.theta_enc_rad"])
    n = 200
    drive = np.zeros((n, sig.OUT_SIZE))
    drive[:, sig.OUT_EFFORT_CMD] = 2.0
    drive[:, sig.OUT_ENABLED] = 1.0
    res = engine.run(n, drive=drive)
    step = 2.0 * math.pi / 1000
    phi = res["rotor.phi"]
    delayed = np.concatenate([np.full(delay, phi[0]), phi[:-delay]])
    np.testing.assert_array_equal(res["meas.theta_enc_rad"], np.floor(delayed / step) * step)


def test_held_inputs_give_the_bits_of_inputs_repeated_per_tick():
    axis = load_axis_config("config/axis_default.yaml")
    dec = 16  # 1 ms NC samples on the 62.5 us base tick
    rows = np.zeros((30, sig.REF_SIZE))
    rows[:, sig.REF_POS_M] = 2e-6 * np.arange(30) ** 2
    rows[:, sig.REF_VEL_M_S] = 4e-3 * np.arange(30)
    rows[:, sig.REF_ACC_M_S2] = 4.0
    n = len(rows) * dec - 5  # the last row holds for fewer ticks
    per_tick = build_engine(axis, output_period_s=1e-3).run(n, ref=np.repeat(rows, dec, axis=0)[:n])
    engine = build_engine(axis, output_period_s=1e-3)
    first = engine.advance(12 * dec, ref=rows[:12], hold=dec)
    rest = engine.advance(n - 12 * dec, ref=rows[12:], hold=dec)
    held = type(first).concat([first, rest])
    assert np.array_equal(per_tick.t, held.t)
    assert np.array_equal(per_tick.data, held.data)
    assert np.max(np.abs(held["table.s"])) > 1e-4  # the axis moved


def test_advance_held_gives_the_bits_of_advance_one_period_at_a_time():
    axis = load_axis_config("config/axis_default.yaml")
    dec = 16  # one 1 ms exchange of 62.5 us ticks per call, as the sim node's drive host
    rows = np.zeros((40, 1, sig.REF_SIZE))
    rows[:, 0, sig.REF_POS_M] = 2e-6 * np.arange(40) ** 2
    rows[:, 0, sig.REF_VEL_M_S] = 4e-3 * np.arange(40)
    plain, held = (build_engine(axis, output_period_s=1e-3) for _ in range(2))
    expected = np.concatenate([plain.advance(dec, ref=row, hold=dec).data for row in rows])
    got = np.array([held.advance_held(row).copy() for row in rows])  # a view: copied at once
    assert np.array_equal(expected, got)
    assert held.k == plain.k == 40 * dec
    assert np.max(np.abs(got[:, held.record_names.index("table.s")])) > 1e-5  # it moved
    held.k += 1
    with pytest.raises(ValueError, match=r"advance_held: at tick 641 with ref of shape \(1, "):
        held.advance_held(rows[0])


def test_noise_drawn_ahead_by_another_engine_gives_the_bits_of_drawing_in_the_loop():
    axis = load_axis_config("config/axis_default.yaml")
    ref = np.zeros((800, sig.REF_SIZE))
    ref[:, sig.REF_POS_M] = 1e-4
    own = build_engine(axis, output_period_s=1e-3)
    assert own.kernel.N_NOISE == 3  # the three current sensors
    drawn = own.run(len(ref), ref=ref)
    engine, other = build_engine(axis, output_period_s=1e-3), build_engine(axis)
    assert engine.noise_key == other.noise_key
    parts = []
    for a, b in ((0, 300), (300, 800)):  # a table of the ticks from the engine's current one
        other.k = a
        parts.append(engine.advance(b - a, ref=ref[a:b], normals=other.standard_normals(b - a)))
    ahead = type(drawn).concat(parts)
    assert np.array_equal(drawn.data, ahead.data)
    assert np.std(drawn["meas.i_a_meas_A"] - drawn["motor.i_a"]) > 0.01  # noise std 0.02 A
    engine.seed = 2
    assert engine.noise_key != other.noise_key


def test_engine_input_errors_name_the_problem(emps):
    engine = build_engine(emps)
    with pytest.raises(ValueError, match=r"ref: shape \(5, 3\) given, expected \(5, 6\)"):
        engine.advance(5, ref=np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"ref: shape \(3, 6\) given, expected \(2, 6\)"):
        engine.advance(8, ref=np.zeros((3, 6)), hold=4)
    with pytest.raises(ValueError, match=r"hold = 0: must be an integer >= 1"):
        engine.advance(8, ref=np.zeros((8, 6)), hold=0)
    with pytest.raises(ValueError, match=r"normals: shape \(7, 0\) given, expected \(8, 0\)"):
        engine.advance(8, normals=np.zeros((7, 0)))
    with pytest.raises(KeyError, match="record: unknown signal.s. table.q"):
        build_engine(emps, record=["table.s", "table.q"])
    with pytest.raises(KeyError, match="signal 'nope': not recorded"):
        engine.run(3)["nope"]
    with pytest.raises(ValueError, match=r"output_period_s = 0.0015: must be an integer multiple"):
        build_engine(emps, output_period_s=1.5e-3)
    with pytest.raises(
        ValueError, match=r"base_period_s = 0.002: the controller's base period is 0.001"
    ):
        Engine(emps.plant, base_period_s=2e-3, controller=engine.controller)
    with pytest.raises(ValueError, match=r"params: shape \(2, 3\) given, expected \(N, 19\)"):
        run_batch(engine, np.zeros((2, 3)), 10)
    with pytest.raises(KeyError, match="parameter 'table.mass': unknown"):
        emps.plant.param_vector({"table.mass": 1.0})
    with pytest.raises(
        ValueError,
        match=r"coordinate table: effective inertia -95.1089 is not positive \(from table.m\)",
    ):
        emps.plant.param_vector({"table.m": -95.1089})


def test_a_friction_too_sharp_for_the_step_is_refused(emps):
    with pytest.raises(
        ValueError,
        match=r"plant.friction: step 0.001 s times damping slope 2.0\d+e\+06 over the effective "
        r"inertia 95.1089 is 21.\d, must be < 2.5 for explicit RK4",
    ):
        Engine(
            emps.plant,
            base_period_s=1e-3,
            substeps=1,
            params=emps.plant.param_vector({"friction.v_reg": 1e-5}),
        )
