"""`feed-twin replay` on a stand-in recording: equal to the offline workflow, and what it writes.

The bag is what a machine would publish: AxisCommand (position, velocity) and JointState
(position [m], effort [N]) at 1 kHz from the stand-in (EMPS model with a current-loop lag,
encoder quantisation and effort noise), whose Coulomb friction rises by 35 % at 7 s.
"""

from __future__ import annotations

import json
import math
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags_support import decode, offered_qos
from test_progress import on_a_terminal

from feed_twin.analysis.cli import simulate_traces
from feed_twin.analysis.compare import compute_metrics
from feed_twin.analysis.synthetic import Unmodelled
from feed_twin.analysis.twin import ModelDoc
from feed_twin.cli import main as cli_main
from feed_twin.io.bag import BagReader, BagWriter, QosProfile
from feed_twin.io.measured import MeasuredDataError, load_column_map, load_measured
from feed_twin.shadow.bagstreams import decode_joint_state, encode_joint_state, read_streams
from feed_twin.shadow.config import load_shadow_config
from feed_twin.shadow.replay import replay
from feed_twin.shadow.standin import StandIn, record_bag

T = 1e-3
F_C = 20.3935
SHADOW_FILE = "config/emps.yaml"
DURATION_S = 14.0


@pytest.fixture(scope="module")
def doc() -> ModelDoc:
    return ModelDoc.load("config/emps.yaml")


@pytest.fixture(scope="module")
def recording(tmp_path_factory, doc) -> dict:
    root = tmp_path_factory.mktemp("replay")
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=0.0)
    changes = [(7.0, "friction.F_c_pos", 1.35 * F_C), (7.0, "friction.F_c_neg", 1.35 * F_C)]
    map_path = record_bag(root / "run", standin, duration_s=DURATION_S, period_s=T, changes=changes)
    return {"root": root, "bag": root / "run", "map": map_path}


@pytest.fixture(scope="module")
def config(tmp_path_factory):
    # the shipped settings with a shorter baseline and window, for a 14 s recording
    cfg = load_shadow_config(SHADOW_FILE)
    data = {k: getattr(cfg, k) for k in cfg.__dataclass_fields__ if k != "standin"}
    data.update(window_s=3.0, baseline_s=4.0, evaluate_period_s=0.5)
    path = tmp_path_factory.mktemp("cfg") / "shadow.yaml"
    import yaml

    path.write_text(yaml.safe_dump({"shadow": data}))
    return path


def test_replay_equals_the_offline_simulation_on_the_same_bag(recording, doc, config) -> None:
    cmap = load_column_map(recording["map"])
    result = replay(recording["bag"], doc, cmap, load_shadow_config(config))
    run = load_measured(recording["bag"], cmap)
    columns = simulate_traces(run, doc)  # what `feed-twin simulate` writes
    offline = compute_metrics(
        run["pos_meas_m"],
        columns["sim_pos_meas_m"],
        run["force_cmd_N"],
        columns["sim_force_cmd_N"],
        effort_unit="N",
    )
    s = result.samples
    assert len(s) == len(run.t_s) == round(DURATION_S / T)
    np.testing.assert_allclose(s.t_s, run.t_s, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(s.x_meas_m, run["pos_meas_m"])
    np.testing.assert_array_equal(s.effort_meas, run["force_cmd_N"])
    # one difference only: the offline sample period comes from the record's end stamps, the
    # replay's from the config; the acceleration feed-forward differs in the last bits
    np.testing.assert_allclose(s.x_twin_m, columns["sim_pos_meas_m"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.effort_twin, columns["sim_force_cmd_N"], rtol=0, atol=1e-9)
    for name, value in offline.as_dict().items():
        if value is None:  # a channel the record does not have (the voltages here)
            assert getattr(result.metrics, name) is None, name
        elif isinstance(value, str):  # the effort's unit
            assert getattr(result.metrics, name) == value, name
        else:
            assert getattr(result.metrics, name) == pytest.approx(value, rel=1e-9), name


@pytest.mark.slow
def test_replay_cli_writes_comparison_bag_rrd_and_report(recording, tmp_path, config) -> None:
    out = tmp_path / "out"
    code = cli_main(
        ["replay", str(recording["bag"]), "--config", "config/emps.yaml", "--shadow", str(config),
         "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    assert report["samples"] == round(DURATION_S / T)
    assert report["faults"]["measured"]["missing"] == 0
    last = report["health"]["last"]
    assert last["effect"] == "coulomb_friction"
    assert last["relative_change"] == pytest.approx(0.35, abs=0.03)
    assert report["health"]["first_warning"]["t_s"] > 7.0
    assert "coulomb_friction +3" in (out / "report.md").read_text()
    assert (out / "replay.rrd").stat().st_size > 10_000
    # the comparison bag, read back by an independent reader
    store = get_typestore(Stores.EMPTY)
    with Reader(out / "comparison") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        for conn in reader.connections:
            store.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
        residual = [c for c in reader.connections if c.topic == "/cnc/x/twin/residual"]
        fe_dev = [
            decode(store, raw, conn.msgtype).following_error_deviation
            for conn, _, raw in reader.messages(connections=residual)
        ]
        health = [c for c in reader.connections if c.topic == "/cnc/x/twin/health"]
        effects = [
            decode(store, raw, conn.msgtype).effect
            for conn, _, raw in reader.messages(connections=health)
        ]
    n = round(DURATION_S / T)
    assert counts == {
        "/cnc/x/command": n,
        "/cnc/x/joint_states": n,
        "/cnc/x/twin/state": n,
        "/cnc/x/twin/residual": n,
        "/cnc/x/twin/health": report["health"]["evaluations"],
    }
    assert report["metrics"]["fe_dev_rms_m"] == pytest.approx(
        math.sqrt(np.mean(np.square(fe_dev))), rel=1e-12
    )
    assert effects[-1] == "coulomb_friction"


@pytest.mark.slow
def test_replay_on_a_terminal_names_its_steps(recording, tmp_path, config) -> None:
    code, shown = on_a_terminal(
        [sys.executable, "-m", "feed_twin.cli", "replay", str(recording["bag"]), "--config",
         "config/emps.yaml", "--shadow", str(config), "--out", str(tmp_path / "out")]
    )  # fmt: skip
    assert code == 0, shown
    for n, name in enumerate(("replaying the bag", "writing the comparison bag",
                              "writing the recording", "writing the report")):  # fmt: skip
        assert f"{name}: {round(100 * n / 4):3d}%|" in shown, shown
    assert "[replay] 14000 samples (13.999 s)" in shown, shown


def test_joint_state_codec_matches_the_generic_decoder(tmp_path) -> None:
    data = encode_joint_state(1_500_000_123, ["x", "y"], [0.1, -0.2], [], [3.5, 4.0])
    assert decode_joint_state(data) == {
        "header.stamp": pytest.approx(1.500000123),
        "name": ["x", "y"],
        "position": (0.1, -0.2),
        "velocity": (),
        "effort": (3.5, 4.0),
    }
    with BagWriter(tmp_path / "js", flush_period_s=None) as writer:
        writer.add_topic("/js", "sensor_msgs/msg/JointState")
        writer.write("/js", data, log_time_ns=1)
    msg = next(BagReader(tmp_path / "js").messages(["/js"])).msg
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_123)
    assert list(msg.name) == ["x", "y"] and list(msg.effort) == [3.5, 4.0]
    with pytest.raises(ValueError, match="JointState: not little-endian CDR"):
        decode_joint_state(b"\x00\x00\x00\x00" + data[4:])


def test_streams_keep_arrival_order_and_machine_stamps(tmp_path) -> None:
    """A message logged late keeps its stamp; the replay sees it where it really arrived."""
    from feed_twin.io.cdr import FlatCodec

    codec = FlatCodec("feed_twin_msgs/msg/AxisCommand")
    bag = tmp_path / "b"
    arrivals = [0, 1, 3, 2, 4]  # slot 2 arrives after slot 3
    with BagWriter(bag, flush_period_s=None) as writer:
        writer.add_topic("/m/command", "feed_twin_msgs/msg/AxisCommand")
        writer.add_topic("/m/joint_states", "sensor_msgs/msg/JointState")
        for i, k in enumerate(arrivals):
            stamp = k * 1_000_000
            writer.write(
                "/m/command",
                codec.encode_map({"header.stamp.nanosec": stamp, "position": 1e-3 * k}),
                log_time_ns=10_000_000 + i * 1_000_000,
            )
            writer.write(
                "/m/joint_states",
                encode_joint_state(stamp, ["x"], [2e-3 * k], [], [float(k)]),
                log_time_ns=10_000_000 + i * 1_000_000 + 300_000,
            )
    map_path = tmp_path / "map.yaml"
    map_path.write_text(
        'time: {column: "/m/command:header.stamp", unit: s}\nposition_sensor: motor_encoder\n'
        'signals:\n  pos_cmd_m: {column: "/m/command:position", unit: mm}\n'
        '  pos_meas_m: {column: "/m/joint_states:position[0]", unit: m}\n'
        '  force_cmd_N: {column: "/m/joint_states:effort[0]", unit: kN}\n'
        "plausibility: {travel_m: 1.0, max_speed_m_s: 1.0}\n"
    )
    streams = read_streams(bag, load_column_map(map_path))
    cmd, meas = streams["command"], streams["measured"]
    np.testing.assert_allclose(cmd.stamp_s, np.array(arrivals) * 1e-3, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cmd.signals["pos_cmd_m"], np.array(arrivals) * 1e-6)  # mm -> m
    np.testing.assert_allclose(meas.signals["force_cmd_N"], np.array(arrivals) * 1e3)  # kN -> N
    assert np.all(np.diff(meas.log_time_ns) > 0)


def test_map_errors_name_the_problem(tmp_path, recording) -> None:
    bad = tmp_path / "two_topics.yaml"
    text = Path(recording["map"]).read_text()
    bad.write_text(text.replace('"/cnc/x/command:velocity"', '"/cnc/x/other:velocity"'))
    with pytest.raises(MeasuredDataError, match="the command signals come from several topics"):
        read_streams(recording["bag"], load_column_map(bad))
    missing = tmp_path / "missing.yaml"
    missing.write_text(text.replace("/cnc/x/joint_states", "/cnc/y/joint_states"))
    with pytest.raises(MeasuredDataError, match="the map names topic '/cnc/y/joint_states', which"):
        read_streams(recording["bag"], load_column_map(missing))
    field = tmp_path / "field.yaml"
    field.write_text(text.replace("effort[0]", "effort[3]"))
    with pytest.raises(MeasuredDataError, match=r"message has no numeric field 'effort\[3\]'"):
        read_streams(recording["bag"], load_column_map(field))


def test_cli_reports_bad_input_on_stderr(recording, tmp_path, capsys) -> None:
    code = cli_main(
        ["replay", str(recording["bag"]), "--config", "config/emps_nominal.yaml",
         "--out", str(tmp_path)]
    )  # fmt: skip
    assert code == 2
    assert "config/emps_nominal.yaml: missing required section shadow" in capsys.readouterr().err


def test_fixed_layout_offsets_follow_the_strings() -> None:
    from feed_twin.io.bag.raw import flat_offsets
    from feed_twin.io.cdr import FlatCodec

    codec = FlatCodec("feed_twin_msgs/msg/AxisCommand")
    for axis in ("x", "spindle_axis"):
        data = codec.encode_map({"axis": axis, "position": 0.25, "line": 7})
        where = flat_offsets(codec, data)
        assert struct.unpack_from("<d", data, where["position"][0])[0] == 0.25
        assert struct.unpack_from("<i", data, where["line"][0])[0] == 7


def test_comparison_bag_keeps_the_recorded_qos_of_the_original_topics(doc, config, tmp_path):
    """The machine's topics keep the QoS its publishers offered (not rosbag2's default), read
    back by rosbags; the twin's topics carry what the live twin node offers."""
    offered = {
        # as ros2_control's joint_state_broadcaster might be configured: best effort, shallow
        "joint_states": (
            QosProfile(reliability="best_effort", depth=1, deadline_s=0.002, lifespan_s=0.5),
        ),
        "command": (QosProfile(depth=5000, durability="transient_local"),),
    }
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=0.0)
    record_bag(tmp_path / "run", standin, duration_s=2.0, period_s=T, qos=offered)
    out = tmp_path / "out"
    code = cli_main(
        ["replay", str(tmp_path / "run"), "--config", "config/emps.yaml", "--shadow",
         str(config), "--out", str(out)]
    )  # fmt: skip
    assert code == 0
    with Reader(out / "comparison") as reader:
        qos = {c.topic: offered_qos(c) for c in reader.connections}
    (js,) = qos["/cnc/x/joint_states"]
    assert (js.reliability.name, js.durability.name, js.depth) == ("BEST_EFFORT", "VOLATILE", 1)
    assert (js.deadline.sec, js.deadline.nsec) == (0, 2_000_000)
    assert (js.lifespan.sec, js.lifespan.nsec) == (0, 500_000_000)
    (cmd,) = qos["/cnc/x/command"]
    assert (cmd.reliability.name, cmd.durability.name, cmd.depth) == (
        "RELIABLE", "TRANSIENT_LOCAL", 5000,
    )  # fmt: skip
    for name in ("state", "residual", "health"):
        (twin,) = qos[f"/cnc/x/twin/{name}"]
        assert (twin.reliability.name, twin.durability.name, twin.depth) == (
            "RELIABLE", "TRANSIENT_LOCAL", 5000,
        )  # fmt: skip
    # the text itself is copied byte for byte (channel metadata of the original mcap)
    original = {t.name: t.offered_qos_profiles for t in BagReader(tmp_path / "run").info.topics}
    copied = {t.name: t.offered_qos_profiles for t in BagReader(out / "comparison").info.topics}
    for topic, text in original.items():
        assert copied[topic] == text


def test_record_bag_rejects_qos_for_an_unknown_topic(doc, tmp_path) -> None:
    standin = StandIn(doc, hidden={}, unmodelled=Unmodelled(), sample_period_s=T, x0_m=0.0)
    with pytest.raises(ValueError, match=r"qos: unknown topic\(s\) \['clock'\]"):
        record_bag(tmp_path / "run", standin, duration_s=0.1, period_s=T,
                   qos={"clock": (QosProfile(),)})  # fmt: skip
