"""Message authentication (feed_twin.nodeset.auth): a signed message reads back unchanged, an
altered, replayed, moved, foreign-keyed or unsigned one is refused and counted by reason, the
replay window is RFC 4303's, and the key reaches a child only through an inherited descriptor
or an owner-only file."""

from __future__ import annotations

import hashlib
import hmac
import os
import subprocess
import sys

import pytest

from feed_twin.io import msg_types
from feed_twin.io.cdr import FlatCodec
from feed_twin.nodeset.auth import (
    BAD_TAG,
    KEY_BYTES,
    KEY_FD_ENV,
    KEY_FILE_ENV,
    PLACEHOLDER,
    REPLAYED,
    UNSIGNED,
    ReplayWindow,
    RunAuth,
    RunKeyError,
    Signer,
    Verifier,
    key_from_environ,
    key_memfd,
    new_key,
    read_key_file,
    write_key_file,
)

TOPIC = "/cnc/x/command"
LAYOUT = FlatCodec(msg_types.AXIS_COMMAND).fixed({"axis": "X"})  # frame_id empty
# numbers in wire order: stamp sec, nanosec, position, velocity, acceleration, line
VALUES = (1, 250_000_000, 0.0125, 0.05, -1.5, 7)


def _signed(signer: Signer, values=VALUES) -> bytes:
    return signer.sign(LAYOUT.encode(values))


def test_a_signed_message_reads_back_byte_for_byte_and_its_tag_is_hmac_sha256():
    key = new_key()
    made = LAYOUT.encode(VALUES)
    data = Signer(key, TOPIC).sign(made)
    padding = -len(made) % 4  # as Fast DDS pads a payload between processes
    assert len(data) == len(made) + 48 + padding and len(data) % 4 == 0
    verifier = Verifier(key, TOPIC)
    assert verifier.verify(data) == made + bytes(padding)
    # every field after the frame_id kept its alignment: the general decoder reads it
    decoded = FlatCodec(msg_types.AXIS_COMMAND).decode_map(data)
    assert (decoded["position"], decoded["line"]) == (VALUES[2], VALUES[5])
    # the signature, recomputed with hashlib's HMAC from the documented construction
    frame_id = decoded["header.frame_id"]
    seq = int(frame_id[:16], 16)
    assert seq & (2**40 - 1) == 1
    placeholder = FlatCodec(msg_types.AXIS_COMMAND).fixed(
        {"axis": "X", "header.frame_id": PLACEHOLDER}
    )
    topic_key = hmac.new(key, b"feed_twin topic " + TOPIC.encode(), hashlib.sha256).digest()
    body = seq.to_bytes(8, "little") + placeholder.encode(VALUES) + bytes(padding)
    assert frame_id[16:] == hmac.new(topic_key, body, hashlib.sha256).digest()[:16].hex()
    assert verifier.refused == {}


def test_two_publishers_on_one_topic_are_told_apart_and_each_replay_is_caught():
    key = new_key()
    first, second = Signer(key, TOPIC), Signer(key, TOPIC)
    verifier = Verifier(key, TOPIC)
    a, b = first.sign(LAYOUT.encode(VALUES)), second.sign(LAYOUT.encode(VALUES))
    assert verifier.verify(a) is not None and verifier.verify(b) is not None
    assert verifier.verify(a) is None and verifier.verify(b) is None
    assert verifier.refused == {REPLAYED: 2}


def test_altered_replayed_moved_and_foreign_messages_are_refused_by_reason():
    key = new_key()
    signer = Signer(key, TOPIC)
    verifier = Verifier(key, TOPIC)
    first = _signed(signer)
    assert verifier.verify(first) is not None
    assert verifier.verify(first) is None  # replayed as it was
    altered = bytearray(_signed(signer))
    altered[-20] ^= 0x01  # a bit of the position setpoint
    assert verifier.verify(bytes(altered)) is None
    renumbered = bytearray(_signed(signer))
    renumbered[16 + 15] ^= 0x01  # another sequence number, same tag
    assert verifier.verify(bytes(renumbered)) is None
    other_topic = _signed(Signer(key, "/cnc/y/command"))
    assert verifier.verify(other_topic) is None
    other_key = _signed(Signer(new_key(), TOPIC))
    assert verifier.verify(other_key) is None
    tokened = FlatCodec(msg_types.AXIS_COMMAND).fixed({"axis": "X", "header.frame_id": "a1b2"})
    assert verifier.verify(tokened.encode(VALUES)) is None
    assert verifier.verify(first[:20]) is None
    big_endian = b"\x00\x00" + first[2:]
    assert verifier.verify(big_endian) is None
    assert verifier.refused == {REPLAYED: 1, BAD_TAG: 4, UNSIGNED: 3}
    assert verifier.verify(_signed(signer)) is not None  # the run's next message still passes


def test_the_signer_needs_an_empty_frame_id():
    tokened = FlatCodec(msg_types.AXIS_COMMAND).fixed({"axis": "X", "header.frame_id": "a1b2"})
    with pytest.raises(ValueError, match=r"^/cnc/x/command: only a little-endian message with an"):
        Signer(new_key(), TOPIC).sign(tokened.encode(VALUES))


def test_texts_are_signed_as_their_last_word():
    key = new_key()
    signer, verifier = Signer(key, "/cnc/program_state"), Verifier(key, "/cnc/program_state")
    text = signer.sign_text("finished 1250000000")
    assert text.startswith("finished 1250000000 #") and len(text.rpartition(" #")[2]) == 48
    assert verifier.verify_text(text) == "finished 1250000000"
    assert verifier.verify_text(text) is None
    forged = signer.sign_text("running").replace("running", "stopped 5")
    assert verifier.verify_text(forged) is None
    assert verifier.verify_text("finished 1 #" + "+" * 48) is None
    assert verifier.verify_text("finished 1") is None
    assert verifier.refused == {REPLAYED: 1, BAD_TAG: 1, UNSIGNED: 2}


def test_the_replay_window_takes_late_messages_once_and_refuses_older_than_its_width():
    window = ReplayWindow(size=8)
    assert [window.check(s) for s in (1, 3, 2, 3, 0, -1)] == [True, True, True, False, False, False]
    assert window.check(20) and window.newest == 20
    assert window.check(13) and not window.check(13)  # 7 behind: inside the window
    assert not window.check(12)  # 8 behind: outside
    assert window.check(10_000) and not window.check(20)


def test_the_key_reaches_a_child_through_a_sealed_descriptor_only():
    key = new_key()
    fd = key_memfd(key)
    try:
        with pytest.raises(PermissionError):
            os.pwrite(fd, b"x" * KEY_BYTES, 0)  # sealed: nobody rewrites the run's key
        child = subprocess.run(
            [sys.executable, "-c",
             "import os; from feed_twin.nodeset.auth import key_from_environ\n"
             "print(key_from_environ(os.environ).hex())\n"
             f"os.fstat({fd})"],
            env={**os.environ, KEY_FD_ENV: str(fd)}, pass_fds=(fd,),
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert child.stdout.strip() == key.hex()
        assert "Bad file descriptor" in child.stderr  # closed once read
        unpassed = subprocess.run(
            [sys.executable, "-c", "import os\nfrom feed_twin.nodeset.auth import "
             "key_from_environ\nkey_from_environ(os.environ)"],
            env={**os.environ, KEY_FD_ENV: str(fd)}, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert f"RunKeyError: {KEY_FD_ENV} = {fd}: cannot read the run key" in unpassed.stderr
    finally:
        os.close(fd)


def test_a_key_file_must_be_its_owners_alone(tmp_path):
    key = new_key()
    path = tmp_path / "run.key"
    write_key_file(path, key)
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert key_from_environ({KEY_FILE_ENV: str(path)}) == key
    with pytest.raises(FileExistsError):
        write_key_file(path, key)
    path.chmod(0o640)
    with pytest.raises(RunKeyError) as error:
        read_key_file(path)
    assert str(error.value) == (
        f"{KEY_FILE_ENV} = {path}: mode 0640, readable beyond its owner; chmod 600 it"
    )
    short = tmp_path / "short.key"
    write_key_file(short, b"abc")
    with pytest.raises(RunKeyError, match=r"holds 3 bytes, not 32$"):
        read_key_file(short)
    with pytest.raises(RunKeyError, match=r"^FEED_TWIN_RUN_KEY_FD = 'x1': not a descriptor"):
        key_from_environ({KEY_FD_ENV: "x1"})
    assert key_from_environ({}) is None


def test_a_nodes_run_auth_signs_and_checks_per_topic_and_is_open_without_a_key():
    key = new_key()
    sender, receiver = RunAuth(key), RunAuth(key)
    data = sender.sign(TOPIC, LAYOUT.encode(VALUES))
    payload = receiver.verify(TOPIC, data)
    assert payload is not None, f"refused: {receiver.last_refusal(TOPIC)}"
    assert LAYOUT.decode(payload) == VALUES
    assert receiver.verify(TOPIC, data) is None and receiver.last_refusal(TOPIC) == REPLAYED
    assert receiver.verify("/cnc/y/command", sender.sign(TOPIC, LAYOUT.encode(VALUES))) is None
    assert receiver.last_refusal("/cnc/y/command") == BAD_TAG
    text = sender.sign_text("/cnc/program_state", "running")
    assert receiver.verify_text("/cnc/program_state", text) == "running"
    open_ = RunAuth(None)
    assert not open_.enabled
    assert open_.sign(TOPIC, b"abc") == b"abc" and open_.verify(TOPIC, b"abc") == b"abc"
    assert open_.verify_text(TOPIC, "x") == "x" and open_.last_refusal(TOPIC) == ""


def test_a_message_is_padded_to_four_bytes_as_fast_dds_delivers_it_between_processes():
    feedback = FlatCodec(msg_types.AXIS_FEEDBACK)
    made = feedback.fixed({"axis": "X"}).encode(tuple(range(len(feedback.names) - 2)))
    assert len(made) % 4 == 2  # Fast DDS would add 2 zero bytes, and not say so
    key = new_key()
    data = Signer(key, "/cnc/x/feedback").sign(made)
    assert Verifier(key, "/cnc/x/feedback").verify(data) == made + b"\0\0"
    assert feedback.decode_map(made + b"\0\0") == feedback.decode_map(made)
