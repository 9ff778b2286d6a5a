"""Hardening without ROS: drive protection, reachability, plausibility, input limits, guards,
disk handling and one-line errors (issue 19)."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from feed_twin.cli import main as cli_main
from feed_twin.core import signals as sig
from feed_twin.core.config import MAX_CONFIG_BYTES, ConfigError, load_yaml
from feed_twin.gcode import GcodeError, load_nc_config, validate_program
from feed_twin.gcode.lexer import MAX_LINE_BYTES
from feed_twin.io.bag import BagError, BagReader, BagWriter, recover
from feed_twin.nodeset.guard import (
    UNKNOWN_NODE_NAME,
    CommandGuard,
    Endpoint,
    bounds_of,
    check_values,
    parse_program_state,
    within_bounds,
)
from feed_twin.nodeset.protection import (
    FAULT_CURRENT_LIMIT,
    FAULT_OVERSPEED,
    DriveLimits,
    DriveProtection,
    describe_trip,
)
from feed_twin.nodeset.reach import capability, check_reachable
from feed_twin.ros.domain import run_domain
from feed_twin.ros.preflight import check_output_dir, complete_rrd
from feed_twin.sim.config import load_axis_config

ROOT = Path(__file__).resolve().parents[1]
AXIS = ROOT / "config" / "axis_default.yaml"
MS = 1_000_000  # [ns]


def limits(**changes) -> DriveLimits:
    base = DriveLimits(following_error_m=2e-3, current_A=30.0, current_time_s=0.5, speed_m_s=0.42)
    return dataclasses.replace(base, **changes)


def test_following_error_trips_at_the_first_exceedance_and_latches():
    guard = DriveProtection(limits(), exchange_ns=MS)
    assert guard.check(0, 1.999e-3, 5.0, 0.1) is None
    trip = guard.check(7 * MS, -2.001e-3, 5.0, 0.1)
    assert trip is not None and trip.code == sig.FAULT_FOLLOWING_ERROR
    assert trip.value == pytest.approx(2.001e-3) and trip.t_ns == 7 * MS
    assert guard.check(8 * MS, 5e-3, 5.0, 0.1) is None  # latched: reported once
    assert guard.trip is trip
    text = trip.text()
    assert (
        "at t = 0.0070 s" in text and "following error 2.001 mm exceeds the limit 2.000 mm" in text
    )
    assert "controller.position.following_error_limit_m" in text


def test_speed_and_nan_trip():
    trip = DriveProtection(limits(), exchange_ns=MS).check(0, 0.0, 0.0, -0.43)
    assert trip is not None, "430 mm/s is beyond the 420 mm/s limit: a trip"
    assert (
        trip.code == FAULT_OVERSPEED and "speed 430.0 mm/s exceeds the limit 420.0" in trip.text()
    )
    nan = DriveProtection(limits(), exchange_ns=MS).check(0, math.nan, 0.0, 0.0)
    assert nan is not None and nan.code == sig.FAULT_FOLLOWING_ERROR


def test_current_at_its_limit_trips_only_after_the_allowed_time():
    # 0.5 s at >= 95 % of 30 A trips at the 501st exchange; a dip below resets the count.
    guard = DriveProtection(limits(), exchange_ns=MS)
    for k in range(300):
        assert guard.check(k * MS, 0.0, 29.0, 0.1) is None
    assert guard.check(300 * MS, 0.0, 20.0, 0.1) is None
    trips = [guard.check((301 + k) * MS, 0.0, -28.6, 0.1) for k in range(501)]
    assert all(t is None for t in trips[:500])
    last = trips[500]
    assert last is not None, "0.5 s at the current limit: a trip at the 501st exchange"
    assert last.code == FAULT_CURRENT_LIMIT
    assert "current 28.60 A at the limit 30.00 A" in last.text()


def test_describe_trip_names_the_program_line():
    run = {"/c": {"header.stamp": np.array([0.0, 0.05, 0.1]), "line": np.array([-1, 2, 3])}}
    reason = "sim node (cnc/x) exited with code 1: drive fault 1 at t = 0.0700 s: following error"
    text = describe_trip(reason, run, "/c", {2: "G0 X-200", 3: "M30"})
    assert text.endswith("(program line 2: G0 X-200)")
    assert describe_trip("other", run, "/c", None) == "other"


def test_reachability_of_the_default_config_and_its_closed_forms():
    axis = load_axis_config(AXIS)
    nc = load_nc_config(AXIS)
    check_reachable(axis, nc, None, source="x")  # the fixed default passes
    cap = capability(axis)
    assert cap is not None, "the default config has a controller and a screw: a capability"
    # no acceleration, no friction: the voltage is the back-EMF p psi_pm omega_m (R_s, L i small)
    bare = dataclasses.replace(cap, F_c_N=0.0, F_v_N_s_m=0.0)
    omega_m = 2.0 * math.pi * 0.3 / 0.01
    assert bare.voltage_at(0.3, 0.0) == pytest.approx(4 * 0.3167 * omega_m, rel=1e-9)
    # torque for a = 3 m/s^2: J_total a 2 pi / lead
    assert bare.current_at(0.0, 3.0) == pytest.approx(5.8e-3 * 3.0 * 2 * math.pi / 0.01 / 1.9)
    assert cap.u_max_V == pytest.approx(0.95 * 560.0 / math.sqrt(3.0))
    v = cap.reachable_speed(3.0)
    assert cap.voltage_at(v, 3.0) == pytest.approx(cap.u_max_V, rel=1e-6)


def _nc_with(**changes):
    nc = load_nc_config(AXIS)
    axes = tuple(
        dataclasses.replace(a, **changes) if a.name == nc.twin_axis else a for a in nc.axes
    )
    return dataclasses.replace(nc, axes=axes)


def test_unreachable_rapid_names_the_limit_and_the_margin():
    axis = load_axis_config(AXIS)
    with pytest.raises(ConfigError) as err:
        check_reachable(axis, _nc_with(rapid_m_s=0.5), None, source="cfg.yaml")
    text = str(err.value)
    assert text.startswith("cfg.yaml: nc.axes[X].rapid_m_s = 0.5: the motor needs 401 V")
    assert "the inverter gives 307 V" in text and "short by 30.6 %" in text
    assert "reaches 0.382 m/s at most" in text
    with pytest.raises(ConfigError, match=r"above the drive's speed limit .* by 16.7 %"):
        check_reachable(axis, load_nc_config(AXIS), 0.3, source="cfg.yaml")
    with pytest.raises(ConfigError, match=r"a_max_m_s2 = 30.0 there needs 57.\d A, above"):
        check_reachable(axis, _nc_with(a_max_m_s2=30.0), None, source="cfg.yaml")


def _axis_yaml(tmp_path: Path, edit) -> Path:
    data = yaml.safe_load(AXIS.read_text())
    edit(data)
    path = tmp_path / "axis.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _table(data: dict) -> dict:
    return next(c for c in data["plant"]["components"] if c["name"] == "table")


@pytest.mark.parametrize("mass", [1e300, 1e-30])
def test_implausible_mass_is_refused_unless_listed_unusual(tmp_path, mass):
    path = _axis_yaml(tmp_path, lambda d: _table(d)["params"].update(m=mass))
    with pytest.raises(ConfigError) as err:
        load_axis_config(path)
    assert f"plant.table.m = {mass!r}: implausible for a feed axis" in str(err.value)
    assert "[0.001, 100000]" in str(err.value) and "plant.unusual" in str(err.value)

    def unusual(d):
        _table(d)["params"].update(m=mass)
        d["plant"]["unusual"] = ["table.m"]

    if mass > 1.0:  # a listed parameter is not range-checked (the tiny one would be stiff)
        assert load_axis_config(_axis_yaml(tmp_path, unusual)).plant is not None
    bad = _axis_yaml(tmp_path, lambda d: d["plant"].update(unusual=["tabel.m"]))
    with pytest.raises(ConfigError, match=r"plant.unusual: tabel.m: no such component parameter"):
        load_axis_config(bad)


def test_long_program_line_is_refused_without_echo(tmp_path):
    program = tmp_path / "long.ngc"
    program.write_text("G1 X" + "1" * 1_000_000 + "\nM30\n")
    with pytest.raises(GcodeError) as err:
        validate_program(program, load_nc_config(AXIS))
    text = str(err.value)
    assert text.startswith(f"{program}:1: the line is longer than {MAX_LINE_BYTES} bytes")
    assert len(text) < 300
    word = GcodeError("bad number", file="p.ngc", line=1, column=1, word="X" + "9" * 5000)
    assert "... (5001 characters)" in str(word) and len(str(word)) < 200


def test_huge_or_unreadable_config_is_one_line(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"a: [" + b"1, " * (MAX_CONFIG_BYTES // 3 + 10) + b"1]\n")
    with pytest.raises(ConfigError, match=r"big.yaml: larger than 4 MB; a configuration is a few"):
        load_yaml(big)
    with pytest.raises(ConfigError, match=r": is a directory, not a config file"):
        load_yaml(tmp_path)


def test_command_values_and_program_states():
    assert check_values({"position": 0.4, "velocity": -0.1}) is None
    assert check_values({"position": math.nan}) == "position = nan"
    assert check_values({"i_q": 2e4}) == "i_q = 20000.0 beyond +/-10000"
    # the per-exchange fast path agrees with check_values on every kind of value
    bounds = bounds_of(("position", "i_q"))
    for values in ((0.4, -1e4), (0.4, math.nan), (math.inf, 0.0), (-1e3, 2e4), (-1000.1, 0.0)):
        named: dict[str, float] = dict(zip(("position", "i_q"), values, strict=True))
        assert within_bounds(values, bounds) == (check_values(named) is None), values
    with pytest.raises(ValueError, match="no ABSURD bound for line"):
        bounds_of(("position", "line"))
    assert parse_program_state("finished 123") == ("finished", 123, "finished 123")
    assert parse_program_state("running") == ("running", None, "running")
    assert parse_program_state("finished notanumber") is None
    assert parse_program_state("launch missiles") is None
    assert parse_program_state("error p.ngc:3: bad") == ("error", None, "error p.ngc:3: bad")
    assert parse_program_state("finished 5" + "0" * 5000) is None


def test_foreign_publishers_are_found_once():
    guard = CommandGuard(own_nodes=frozenset({"gcode", "controller"}), namespace="/cnc/x")
    own = Endpoint(node_name="gcode", node_namespace="/cnc/x", gid="01")
    other = Endpoint(node_name="intruder", node_namespace="/", gid="02")
    pending = Endpoint(node_name=UNKNOWN_NODE_NAME, node_namespace="_X_", gid="03")
    assert guard.foreign([own, pending]) == []
    assert guard.foreign([own, other]) == [other]
    assert guard.foreign([own, other]) == []  # reported once
    copy = Endpoint(node_name="gcode", node_namespace="/cnc/x", gid="04")
    assert {e.gid for e in guard.foreign([own, copy])} == {"01", "04"}  # two of one node
    assert Endpoint(node_name="n", node_namespace="/a/", gid="9").describe() == (
        "node '/a/n' (publisher gid 9)"
    )


def test_output_dir_checks(tmp_path):
    check_output_dir(tmp_path / "new", 1000)
    assert (tmp_path / "new").is_dir() and not list((tmp_path / "new").iterdir())
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(
        ConfigError, match=r"--out .*file/sub: cannot create it \(Not a directory\)"
    ):
        check_output_dir(blocker / "sub", 1000)
    with pytest.raises(
        ConfigError, match=r"MB free, the run needs about .* MB \(bag 1000000000\.0 MB"
    ):
        check_output_dir(tmp_path, 10**15)


def test_domain_of_a_run(monkeypatch):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert run_domain(17) == (None, 17)
    reservation, domain = run_domain(None)
    assert reservation is not None, "without ROS_DOMAIN_ID a run reserves a domain"
    try:
        assert domain == reservation.domain_id
        other, second = run_domain(None)
        assert other is not None, "a second run without ROS_DOMAIN_ID reserves one too"
        assert second != domain  # a second run on the host gets another domain
        other.release()
    finally:
        reservation.release()
    monkeypatch.setenv("ROS_DOMAIN_ID", "33")
    assert run_domain(None) == (None, 33)
    monkeypatch.setenv("ROS_DOMAIN_ID", "x")
    with pytest.raises(ValueError, match=r"ROS_DOMAIN_ID = 'x': must be a whole number"):
        run_domain(None)
    with pytest.raises(ValueError, match=r"--domain-id 300: must lie in \[0, 232\]"):
        run_domain(300)


def test_rrd_without_footer_is_incomplete(tmp_path):
    import rerun as rr

    path = tmp_path / "a.rrd"
    rec = rr.RecordingStream("test_hardening")
    rec.save(str(path))
    for i in range(200):
        rec.set_time("t", duration=i * 1e-3)
        rec.log("x", rr.Scalars(float(i)))
    rec.disconnect()
    assert complete_rrd(path)
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(path.read_bytes()[:-100])
    assert not complete_rrd(cut) and not complete_rrd(tmp_path / "none.rrd")


WRITE_UNTIL_FULL = """
import resource, signal, sys
from feed_twin.io.bag import BagError, BagWriter
from std_msgs.msg import Float64
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
bag = BagWriter(sys.argv[1], flush_period_s=None, compression="none")
bag.add_topic("/x", "std_msgs/msg/Float64")
payload = bytes(4) + bytes(8)
flushed = 0
for k in range(100_000):
    bag.write("/x", payload, log_time_ns=k * 1000)
    if k % 1000 == 999:
        bag.flush()
        if bag.error is None:
            flushed = k + 1
print(bag.error is not None, bag.dropped > 0)
print("flushed", flushed)
try:
    bag.close()
except BagError as exc:
    print("closed:", exc)
"""


def test_bag_writer_stops_cleanly_when_the_file_system_refuses(tmp_path):
    bag = tmp_path / "bag"
    done = subprocess.run(
        [sys.executable, "-c", WRITE_UNTIL_FULL, str(bag)],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    assert done.stdout.splitlines()[0] == "True True", done.stderr
    assert "closed:" in done.stdout and "recording stopped: File too large" in done.stdout
    flushed = int(done.stdout.splitlines()[1].split()[1])
    result = recover(bag)
    # Every message of a flush that succeeded is back; the chunk whose write failed is lost.
    assert flushed >= 2000 and result.messages_recovered == flushed
    assert not result.was_complete
    assert not list(bag.glob("*.recovering"))
    assert len(BagReader(bag).columns("/x", ["data"])["data"]) == result.messages_recovered


def test_closed_bag_rejects_writes(tmp_path):
    with BagWriter(tmp_path / "b") as bag:
        bag.add_topic("/x", "std_msgs/msg/Float64")
    with pytest.raises(BagError, match="the bag is closed"):
        bag.write("/x", bytes(12), log_time_ns=0)


def test_cli_errors_are_one_line(tmp_path, capsys):
    bad = _axis_yaml(tmp_path, lambda d: _table(d)["params"].update(m=-3.0))
    assert cli_main(["model", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "plant.table.m = -3.0: must be > 0" in err
    assert cli_main(["model", "--config", str(tmp_path / "nope.yaml")]) == 2
    assert "nope.yaml: no such config file" in capsys.readouterr().err


def test_plan_into_a_closed_pipe_ends_quietly():
    cmd = (
        f"{sys.executable} -m feed_twin.cli plan {ROOT}/tests/fixtures/gcode/sample.ngc "
        f"--config {AXIS} --out /dev/stdout | head -n 1; echo rc ${{PIPESTATUS[0]}}"
    )
    done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=120)
    assert done.stdout.splitlines()[-1] == "rc 141"
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr


def test_measured_csv_errors_are_one_line(tmp_path):
    from feed_twin.io.measured import MeasuredDataError, read_csv_table

    binary = tmp_path / "b.csv"
    binary.write_bytes(b"t_s,x\n\x00\x01")
    with pytest.raises(
        MeasuredDataError, match=r"b.csv: is not a text CSV \(binary data at byte 6\)"
    ):
        read_csv_table(binary)
    ragged = tmp_path / "r.csv"
    ragged.write_text("t_s,x\n0,1\n1\n2,3\n")
    with pytest.raises(
        MeasuredDataError, match=r"r.csv: line 3 has 1 cells but the header has 2 columns"
    ):
        read_csv_table(ragged)


def test_bag_info_gives_wall_and_simulated_duration(tmp_path, capsys):
    import struct

    bag = tmp_path / "clock_bag"
    with BagWriter(bag) as writer:
        writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        for k in range(21):  # stamps 0 .. 2 s, received over 0.1 s of wall time
            data = bytes(4) + struct.pack("<iI", *divmod(k * 100_000_000, 1_000_000_000))
            writer.write("/clock", data, log_time_ns=k * 5_000_000)
    assert cli_main(["bag", "info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "duration:  0.100000 s wall clock (receive times)" in out
    assert "simulated: 2.000000 s (/clock stamps)" in out


def test_exit_status_of_a_killed_node():
    from feed_twin.ros.preflight import exit_status

    assert exit_status(-9) == 137 and exit_status(130) == 130 and exit_status(0) == 0


def test_limits_of_the_default_config(tmp_path):
    from feed_twin.nodeset.config import load_node_set_config
    from feed_twin.nodeset.protection import protection_for_config

    guard = protection_for_config(AXIS, load_node_set_config(AXIS), MS)
    assert guard is not None, "the default config's protection is on"
    assert guard.limits == DriveLimits(
        following_error_m=2e-3, current_A=30.0, current_time_s=0.5, speed_m_s=1.2 * 0.35
    )
    off = _axis_yaml(tmp_path, lambda d: d["ros"].update(protection={"enabled": False}))
    assert protection_for_config(off, load_node_set_config(off), MS) is None


def test_the_json_line_is_strict_json_with_null_for_a_figure_without_value():
    from feed_twin.nodeset.summary import json_line

    line = json_line({"current_peak_A": float("nan"), "x": [1.0, float("inf")], "n": {"y": 2}})

    def refuse(name):
        raise AssertionError(f"non-standard JSON constant {name}")

    assert json.loads(line, parse_constant=refuse) == {
        "current_peak_A": None,
        "x": [1.0, None],
        "n": {"y": 2},
    }
