"""The shadow twin against a stand-in machine (EMPS model), in process.

- identity: streamed sample by sample, the twin gives bit for bit what the discrepancy
  workflow's batch simulation gives on the same command (Twin.simulate);
- message faults on both streams never stall it, are counted as injected, and leave the
  twin's own samples untouched where only the measurement was hit;
- health: a Coulomb friction raised by 35 % in the middle of the run is named with its size,
  and the same run without a change raises no warning at all.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from feed_twin.analysis.synthetic import Unmodelled
from feed_twin.analysis.twin import Drive, ModelDoc, Twin
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.health import OK, STALE, WARN
from feed_twin.shadow.standin import EFFORT_SAMPLE, StandIn, program_command
from feed_twin.shadow.twin import ResidualBlock, ShadowTwin

T = 1e-3
F_C = 20.3935  # [N] Coulomb friction of config/emps.yaml
SHADOW = {
    "sample_period_s": T,
    "stamp_tolerance": 0.25,
    "reorder_window": 5,
    "missing_fill": "interpolate",
    "missing_flag_after": 20,
    "window_s": 3.0,
    "baseline_s": 4.0,
    "evaluate_period_s": 0.5,
    "fe_dev_rms_warn_m": 2.0e-6,
    "fe_dev_rms_error_m": 2.0e-5,
    "effort_dev_rms_warn": 1.5,
    "effort_dev_rms_error": 15.0,
}


@pytest.fixture(scope="module")
def doc() -> ModelDoc:
    return ModelDoc.load("config/emps.yaml")


@pytest.fixture(scope="module")
def config():
    return load_shadow_config({"shadow": SHADOW}, source="test")


def machine_run(doc: ModelDoc, duration_s: float, raise_at_s: float | None = None) -> dict:
    """The stand-in answering the repeated program; friction x1.35 from raise_at_s."""
    t, x, v, a = program_command(duration_s, T)
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=x[0])
    xm, em = np.zeros_like(t), np.zeros_like(t)
    step = 100
    for k0 in range(0, len(t), step):
        if raise_at_s is not None and t[k0] >= raise_at_s:
            standin.set_parameter("friction.F_c_pos", 1.35 * F_C)
            standin.set_parameter("friction.F_c_neg", 1.35 * F_C)
        sl = slice(k0, k0 + step)
        xm[sl], em[sl] = standin.step(x[sl], v[sl], a[sl])
    return {"t": t, "x": x, "v": v, "xm": xm, "em": em}


@pytest.fixture(scope="module")
def clean(doc) -> dict:
    return machine_run(doc, 3.0)


def shadow_of(
    doc, config, *, command_velocity: bool = True, effort_sample: str = EFFORT_SAMPLE
) -> ShadowTwin:
    """The shadow of the stand-in (its effort: the command issued at each stamp)."""
    return ShadowTwin(
        Twin.compile(doc),
        config,
        command_velocity=command_velocity,
        travel_m=0.3,
        effort_sample=effort_sample,  # type: ignore[arg-type]
    )


def stream_through(shadow: ShadowTwin, run: dict, *, with_velocity: bool = True) -> ResidualBlock:
    blocks = []
    for k in range(len(run["t"])):
        vel = run["v"][k] if with_velocity else None
        shadow.push_command(run["t"][k], run["x"][k], vel)
        shadow.push_measured(run["t"][k], run["xm"][k], run["em"][k])
        if k % 37 == 0:
            b = shadow.process()
            if b is not None:
                blocks.append(b)
    b = shadow.process(final=True)
    if b is not None:
        blocks.append(b)
    return ResidualBlock.concat(blocks)


def shadow_without_effort(doc, config) -> ShadowTwin:
    return ShadowTwin(
        Twin.compile(doc),
        config,
        command_velocity=True,
        travel_m=0.3,
        effort_sample=EFFORT_SAMPLE,
        measured_effort=False,
    )


def offline(doc: ModelDoc, run: dict, vel: np.ndarray, effort_actual: bool = False):
    twin = Twin.compile(doc)
    drive = Drive(
        t_s=run["t"],
        pos_ref_m=run["x"],
        vel_ref_m_s=vel,
        acc_ref_m_s2=np.gradient(vel, T),
        effort_add=None,
        force_ext_N=None,
        x0_m=float(run["xm"][0]),
        sensor="motor_encoder",
        effort_actual=effort_actual,
    )
    out = twin.simulate(drive, twin.nominal[None, :])
    assert out.effort is not None
    return out.x_m[0], out.effort[0]


@pytest.mark.parametrize(
    ("with_velocity", "effort_sample"),
    [(True, "setpoint"), (False, "setpoint"), (True, "actual")],
)
def test_streamed_twin_is_bit_identical_to_the_batch_simulation(
    doc, config, clean, with_velocity, effort_sample
) -> None:
    """Also with the effort stamped as a drive's actual value (the command of the base tick
    before each sample), carried across the streamed path's advances: config/emps.yaml runs
    10 sub-steps per tick (its engine.substeps), both paths alike."""
    shadow = shadow_of(doc, config, command_velocity=with_velocity, effort_sample=effort_sample)
    assert shadow.engine.nsub == doc.data["engine"]["substeps"] == 10
    got = stream_through(shadow, clean, with_velocity=with_velocity)
    vel = clean["v"] if with_velocity else np.gradient(clean["x"], T)
    x_ref, effort_ref = offline(doc, clean, vel, effort_actual=effort_sample == "actual")
    assert len(got) == len(clean["t"])
    np.testing.assert_array_equal(got.x_twin_m, x_ref)
    np.testing.assert_array_equal(got.effort_twin, effort_ref)
    np.testing.assert_array_equal(got.fe_dev_m, x_ref - clean["xm"])
    np.testing.assert_array_equal(got.effort_dev, clean["em"] - effort_ref)
    # the rolling RMS of the last sample is the RMS of the whole (shorter than window) run
    assert got.fe_dev_rms_m[-1] == pytest.approx(np.sqrt(np.mean(got.fe_dev_m**2)), rel=1e-9)


def test_message_faults_are_counted_and_never_stall_the_twin(doc, config, clean) -> None:
    n = len(clean["t"])
    rng = np.random.default_rng(7)
    lost = set(rng.choice(np.arange(10, n - 10), 60, replace=False).tolist())
    dup = sorted(set(rng.choice(np.arange(10, n - 10), 25, replace=False).tolist()) - lost)
    swapped = [k for k in range(100, n - 100, 211) if k not in lost and k + 1 not in lost]
    late = [k for k in range(150, n - 100, 397) if k not in lost and k not in swapped]
    order: list[int] = []
    for k in range(n):
        if k in lost or k in late:
            continue
        order.append(k)
        if k in dup:
            order.append(k)
        if k - 8 in late:
            order.append(k - 8)  # 8 slots late: beyond the 5-slot window
    for k in swapped:
        i = order.index(k)
        order[i], order[i + 1] = order[i + 1], order[i]
    shadow = shadow_of(doc, config)
    blocks = []
    cmd_lost = 1500
    sent = 0  # the commands arrive in time and in order, one of them is lost
    for j, k in enumerate(order):
        while sent <= k:
            if sent != cmd_lost:
                shadow.push_command(clean["t"][sent], clean["x"][sent], clean["v"][sent])
            sent += 1
        shadow.push_measured(clean["t"][k], clean["xm"][k], clean["em"][k])
        if j % 50 == 0 and (b := shadow.process()) is not None:
            blocks.append(b)
    for k in range(sent, n):
        shadow.push_command(clean["t"][k], clean["x"][k], clean["v"][k])
    blocks.append(shadow.process(final=True))
    got = ResidualBlock.concat([b for b in blocks if b is not None])
    assert len(got) == n  # every slot came out, none twice
    c = shadow.measured.counts
    assert c.duplicated == len(dup)
    assert c.late == len(late)
    assert c.missing == len(lost) + len(late)
    assert c.reordered == len(swapped)
    assert shadow.commands.counts.missing == 1
    np.testing.assert_array_equal(np.flatnonzero(got.measured_filled), sorted(lost | set(late)))
    assert np.flatnonzero(got.command_filled).tolist() == [cmd_lost]
    real = ~got.measured_filled
    np.testing.assert_array_equal(got.x_meas_m[real], clean["xm"][real])
    # the lost command sample is interpolated; on a smooth command the twin barely notices
    x_ref, _ = offline(doc, clean, clean["v"])
    assert np.max(np.abs(got.x_twin_m - x_ref)) < 1e-7


def test_a_silent_measurement_stream_makes_the_twin_stale(doc, config) -> None:
    run = machine_run(doc, 7.0)
    stop = 5000  # the measurement stops after 5 s, the commands go on
    shadow = shadow_of(doc, config)
    blocks = []
    for k in range(len(run["t"])):
        shadow.push_command(run["t"][k], run["x"][k], run["v"][k])
        if k < stop:
            shadow.push_measured(run["t"][k], run["xm"][k], run["em"][k])
        if k % 100 == 0 and (b := shadow.process()) is not None:
            blocks.append(b)
    got = ResidualBlock.concat(blocks)
    lead = shadow.silent_lead
    assert lead == 500  # SILENT_AFTER_S at 1 kHz
    # the pairing keeps going: only the lead plus one processing step behind the commands
    assert len(got) >= len(run["t"]) - lead - 1 - 100 - 1
    assert shadow.health.last is not None and shadow.health.last.level == STALE
    assert "no measured samples for 20 cycles or more" in shadow.health.last.message


def test_raised_friction_is_named_with_its_size(doc, config) -> None:
    run = machine_run(doc, 14.0, raise_at_s=7.0)
    shadow = shadow_of(doc, config)
    stream_through(shadow, run)
    verdicts = shadow.health.verdicts
    before = [v for v in verdicts if v.t_s < 7.0]
    assert before and all(v.level == OK for v in before)
    settled = [v for v in verdicts if v.t_s >= 7.0 + SHADOW["window_s"] + 0.5]
    assert settled and all(v.level == WARN for v in settled)
    for v in settled:
        assert v.effect == "coulomb_friction"
        assert v.parameter == "plant.friction.F_c" and v.unit == "N"
        assert v.nominal_value == pytest.approx(F_C)
        # the stand-in's friction went up by 0.35 * 20.39 N = 7.14 N
        assert v.relative_change == pytest.approx(0.35, abs=0.03)
        assert v.message.startswith("coulomb_friction +3")
        assert "% since start" in v.message


def test_no_change_no_warning_over_the_whole_run(doc, config) -> None:
    run = machine_run(doc, 14.0)
    shadow = shadow_of(doc, config)
    stream_through(shadow, run)
    verdicts = shadow.health.verdicts
    assert len(verdicts) == pytest.approx((14.0 - SHADOW["baseline_s"]) / 0.5, abs=1.5)
    assert all(v.level == OK for v in verdicts), [v.message for v in verdicts if v.level]
    last = verdicts[-1]
    assert last.effort_dev_rms - last.baseline_effort_dev_rms < SHADOW["effort_dev_rms_warn"] / 3
    assert math.isnan(last.relative_change) and last.effect == ""


def test_sample_period_must_fit_the_model(doc) -> None:
    cfg = load_shadow_config({"shadow": {**SHADOW, "sample_period_s": 1.5e-3}}, source="test")
    with pytest.raises(ValueError, match=r"shadow.sample_period_s = 0.0015: must be a whole "):
        shadow_of(doc, cfg)


def test_the_effort_sample_must_be_one_a_column_map_knows(doc, config) -> None:
    with pytest.raises(ValueError, match="effort_sample = 'measured': must be one of actual, "):
        shadow_of(doc, config, effort_sample="measured")


def test_command_velocity_is_required_when_configured(doc, config) -> None:
    shadow = shadow_of(doc, config)
    with pytest.raises(ValueError, match="push_command: this twin takes the command velocity"):
        shadow.push_command(0.0, 0.0)


def test_a_diverging_twin_is_restarted_not_stopped(doc, config, clean) -> None:
    from feed_twin.sim.engine import DivergenceError

    shadow = shadow_of(doc, config)
    real_advance = shadow.engine.advance
    calls = {"n": 0}

    def advance(n_ticks, **inputs):
        calls["n"] += 1
        if calls["n"] == 3:
            raise DivergenceError("simulation diverged at t = 0.1 s (test)")
        return real_advance(n_ticks, **inputs)

    shadow.engine.advance = advance
    got = stream_through(shadow, clean)
    assert len(got) == len(clean["t"])
    assert shadow.twin_restarts == 1
    assert "diverged" in shadow.last_restart_message
    lost = ~np.isfinite(got.x_twin_m)
    assert 0 < lost.sum() <= 37 + 1  # the block that diverged, no more
    # restarted at the measured position, the twin follows the machine again
    assert np.max(np.abs(got.fe_dev_m[-1000:])) < 1e-5


def test_without_measured_effort_the_fe_deviation_warns_and_a_position_effect_is_named(
    doc, config
) -> None:
    from feed_twin.analysis.effects import BY_NAME

    run = machine_run(doc, 14.0, raise_at_s=7.0)
    run["em"] = np.full_like(run["em"], np.nan)  # the machine reports no effort
    shadow = shadow_without_effort(doc, config)
    got = stream_through(shadow, run)
    assert np.isnan(got.effort_dev).all()
    verdicts = shadow.health.verdicts
    assert all(v.level == OK for v in verdicts if v.t_s < 7.0)
    settled = [v for v in verdicts if v.t_s >= 7.0 + SHADOW["window_s"] + 0.5]
    assert settled and all(v.level == WARN for v in settled)
    # more friction makes the table lag behind the twin in the direction of motion
    assert all(BY_NAME[v.effect].domain == "position" for v in settled), settled[-1].message
    assert settled[-1].message.endswith("um, effort deviation RMS +0 N since start")


def test_a_model_gap_from_the_start_is_said_once_and_is_not_an_alarm(doc, config) -> None:
    # a controller whose servo is not the twin's (LinuxCNC's HAL loop beside the twin's
    # cascade): its following error differs by 0.5 ms of lag, 5 um of offset and 20 um per
    # m/s^2 from the first sample on, and it reports no effort
    run = machine_run(doc, 14.0)
    a = np.gradient(run["v"], T)
    run["xm"] = run["xm"] - (5e-6 + 5e-4 * run["v"] + 2e-5 * a)
    run["em"] = np.full_like(run["em"], np.nan)
    shadow = shadow_without_effort(doc, config)
    stream_through(shadow, run)
    verdicts = shadow.health.verdicts
    gaps = [v for v in verdicts if v.effect == "model_gap"]
    assert len(gaps) == 1 and gaps[0].level == WARN
    assert gaps[0].message.startswith("model gap from the start: FE deviation RMS ")
    assert "feed-twin diagnose <this run's bag> --config <axis config> --out <dir>" in (
        gaps[0].message
    )
    # the gap is learnt: offset and lag recovered, and no alarm after it
    gap = shadow.health.gap_model
    assert gap is not None and gap[1] == pytest.approx(5e-4, rel=0.05)
    later = [v for v in verdicts if v is not gaps[0]]
    assert later and all(v.level == OK for v in later), later[-1].message


def test_a_measurement_that_never_comes_neither_stalls_nor_grows(doc, config, clean) -> None:
    shadow = shadow_of(doc, config)
    rows = 0
    for k in range(len(clean["t"])):
        shadow.push_command(clean["t"][k], clean["x"][k], clean["v"][k])
        if k % 100 == 0 and (b := shadow.process()) is not None:
            rows += len(b)
            assert np.isnan(b.x_meas_m).all() and b.measured_filled.all()
            assert np.isfinite(b.x_twin_m).all()  # started at the commanded position
    # only the silent lead (plus one processing step) behind the commands, nothing buffered
    assert rows >= len(clean["t"]) - shadow.silent_lead - 100 - 2
    assert shadow.commands.pending_count <= shadow.lookahead + 100
    assert shadow.health.baseline is None  # nothing to judge the machine by
    assert shadow.health.last is not None and shadow.health.last.level == STALE


def test_verdicts_do_not_depend_on_how_the_rows_are_grouped(doc, config) -> None:
    """The live twin hands health one row per cycle, the replay a second of rows at a time:
    both must give the same verdicts (none before the baseline is complete)."""
    from feed_twin.shadow.health import HealthMonitor
    from feed_twin.shadow.twin import physical_effects

    twin = Twin.compile(doc)
    t, x, v, a = program_command(9.0, T)
    rng = np.random.default_rng(3)
    effort_twin = 95.0 * a + 203.5 * v + F_C * np.tanh(v / 1e-3)
    rows = np.column_stack(
        [t, x, 1e-8 * rng.standard_normal(len(t)), 0.5 * rng.standard_normal(len(t)), effort_twin]
    )
    valid = np.ones(len(t), dtype=bool)
    valid[1000:1040] = False  # filled samples inside the baseline

    def verdicts(chunk: int) -> list[tuple[float, int]]:
        health = HealthMonitor(
            config, physical=physical_effects(twin), effort_unit="N", lead_m=twin.lead_m,
            pole_pairs=None, travel_m=0.3,
        )  # fmt: skip
        out = []
        for k in range(0, len(t), chunk):
            out += health.update(rows[k : k + chunk], valid=valid[k : k + chunk])
        return [(round(v.t_s, 9), v.level) for v in out]

    one_by_one = verdicts(1)
    # judged every 0.5 s of rows; the baseline (4000 valid rows) completes at row 4039, so the
    # evaluation at row 3999 says nothing and the first verdict comes at 4.5 s
    assert one_by_one[0][0] == pytest.approx(4.5 - T)
    assert [v[0] for v in one_by_one] == pytest.approx(list(np.arange(4.5, 9.01, 0.5) - T))
    for chunk in (7, 250, 1000, len(t)):
        assert verdicts(chunk) == one_by_one, chunk
