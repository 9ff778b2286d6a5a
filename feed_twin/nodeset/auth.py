"""Message authentication inside a run: a per-run key, a tag per message, a replay window.

Why: the run token that the nodes used to put in `header.frame_id` travels in clear on the
topic, so any process that subscribes can copy it and command the axis (issue 29: commands
re-sent 1.5 mm off moved the table 203 um). The Fast DDS in the ROS 2 Jazzy wheels has no DDS
Security plugins (README, "Protection, isolation and failures"), so the run authenticates its
own messages:

- **Key.** `feed-twin run` draws 32 random bytes per run (`new_key`) and hands them to its
  nodes only through an inherited file descriptor (a sealed memfd, KEY_FD_ENV names its number)
  or, for a run spread over several computers, a file that only its owner may read
  (KEY_FILE_ENV; `read_key_file` refuses one that its group or others can read). The key never
  goes on a topic, the command line or the environment.
- **Tag.** Each topic has its own key, HMAC-SHA256(run key, "feed_twin topic " + name), so a
  message cannot be moved to another topic. The nodes make their messages with an empty
  `header.frame_id`; `Signer.sign` puts the signature there on the way out: 16 hex digits of
  a sequence number and the first 128 bits of HMAC-SHA256(topic key, sequence (8 bytes) + the
  message's CDR bytes with that frame_id set to PLACEHOLDER, 48 '0's). The frame_id grows by
  48 bytes, a multiple of 8, so every later field keeps its CDR alignment; `Verifier.verify`
  checks and gives back the message with its empty frame_id, byte for byte what the node made
  (what the decoders read and the recorder records), up to the zeros that pad it to a multiple
  of 4 bytes: Fast DDS pads every payload so between processes, without a mark of it, so the
  signer pads first and the tag covers what every receiver gets. A text message (program_state,
  run_state, heartbeat) ends in " #" + the same 48 characters over its text.
- **Replay.** A sequence number is a publisher's random 24-bit stream number and a 40-bit
  count from 1 (several nodes publish on one topic: heartbeats, health). Each receiver keeps,
  per stream, a sliding window of the counts it took (RFC 4303's anti-replay window, WINDOW
  wide): a count seen before, or older than the window, is refused.

What it defends against: any process on the host or the network that reads the topics and
writes on them (another run, a replayed bag, a tool, a copied or altered message) but cannot
read the run's key. Not against a process that can read the key: the same user reading
`/proc/<pid>/fd` or the memory of a node, or root. Pure: the ROS nodes pass bytes in.
"""

from __future__ import annotations

import fcntl
import hashlib
import hmac
import os
import secrets
import stat
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

KEY_BYTES = 32
KEY_FD_ENV = "FEED_TWIN_RUN_KEY_FD"  # the number of an inherited descriptor holding the key
KEY_FILE_ENV = "FEED_TWIN_RUN_KEY_FILE"  # or a file readable by its owner only
SEQ_HEX = 16  # sequence number: 64 bits as hex digits
COUNT_BITS = 40  # its low bits count a publisher's messages; the high 24 name its stream
MAX_STREAMS = 256  # publishers a receiver tells apart on one topic
TAG_BYTES = 16  # HMAC-SHA256 truncated to 128 bits (NIST SP 800-107: at least 64 bits)
SIGNATURE_CHARS = SEQ_HEX + 2 * TAG_BYTES  # the frame_id of a signed message
PLACEHOLDER = "0" * SIGNATURE_CHARS  # the frame_id the tag is computed over
WINDOW = 1024  # sequence numbers a receiver remembers behind the newest one
# A CDR message with a Header first: encapsulation (4 bytes), stamp (sec, nanosec: 8), then
# frame_id's length (uint32, with its terminating NUL) and its characters.
CDR_LE = b"\x00\x01"  # little-endian CDR, the encapsulation every ROS 2 publisher here uses
FRAME_ID_LENGTH_AT = 12
FRAME_ID_AT = 16
SIGNED_LENGTH = (SIGNATURE_CHARS + 1).to_bytes(4, "little")
EMPTY_LENGTH = (1).to_bytes(4, "little")  # an empty frame_id: its terminating NUL only
_PLACEHOLDER_BYTES = PLACEHOLDER.encode()
TEXT_MARK = " #"

# Why a message is refused (the count's key in `Verifier.refused`).
UNSIGNED = "unsigned"  # no signature where the run's messages carry one
BAD_TAG = "bad tag"  # altered, or signed with another key
REPLAYED = "replayed"  # a sequence number seen before or older than the window


class RunKeyError(ValueError):
    """The run key cannot be read (one line naming where it was looked for)."""


def new_key() -> bytes:
    return secrets.token_bytes(KEY_BYTES)


def key_memfd(key: bytes) -> int:
    """A sealed, close-on-exec memfd holding `key`: give it to child processes with
    `pass_fds` and its number in KEY_FD_ENV."""
    fd = os.memfd_create("feed_twin_run_key", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
    os.write(fd, key)
    fcntl.fcntl(
        fd,
        fcntl.F_ADD_SEALS,
        fcntl.F_SEAL_WRITE | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_SEAL,
    )
    return fd


def read_key_fd(fd: int) -> bytes:
    try:
        key = os.pread(fd, KEY_BYTES + 1, 0)
    except OSError as exc:
        raise RunKeyError(
            f"{KEY_FD_ENV} = {fd}: cannot read the run key ({exc.strerror})"
        ) from None
    if len(key) != KEY_BYTES:
        raise RunKeyError(
            f"{KEY_FD_ENV} = {fd}: holds {len(key)} bytes, not a {KEY_BYTES}-byte key"
        )
    return key


def read_key_file(path: Path) -> bytes:
    """The key in a file that only its owner may read or write (as ssh's private keys)."""
    try:
        with open(path, "rb") as handle:
            mode = os.fstat(handle.fileno()).st_mode
            key = handle.read(KEY_BYTES + 1)
    except OSError as exc:
        raise RunKeyError(f"{KEY_FILE_ENV} = {path}: cannot read it ({exc.strerror})") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise RunKeyError(
            f"{KEY_FILE_ENV} = {path}: mode {stat.S_IMODE(mode):04o}, readable beyond its "
            "owner; chmod 600 it"
        )
    if len(key) != KEY_BYTES:
        raise RunKeyError(f"{KEY_FILE_ENV} = {path}: holds {len(key)} bytes, not {KEY_BYTES}")
    return key


def write_key_file(path: Path, key: bytes) -> None:
    """Write `key` to a new file of mode 0600 (refuses to replace an existing one)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        os.write(fd, key)
    finally:
        os.close(fd)


def key_from_environ(environ: Mapping[str, str]) -> bytes | None:
    """The run key a node was given (None: it runs unauthenticated, outside `feed-twin run`).
    The descriptor is closed once read, so that the node's own children do not inherit it."""
    fd_text = environ.get(KEY_FD_ENV, "")
    if fd_text:
        if not fd_text.isdigit():
            raise RunKeyError(f"{KEY_FD_ENV} = {fd_text[:40]!r}: not a descriptor number")
        key = read_key_fd(int(fd_text))
        os.close(int(fd_text))
        return key
    path = environ.get(KEY_FILE_ENV, "")
    return read_key_file(Path(path)) if path else None


def topic_key(key: bytes, topic: str) -> bytes:
    return hmac.digest(key, b"feed_twin topic " + topic.encode(), "sha256")


def _keyed(key: bytes) -> hmac.HMAC:
    """HMAC-SHA256 with its key set up once: each tag copies it (about 1 us less a message
    than `hmac.digest`, which pads and hashes the key every time)."""
    return hmac.new(key, digestmod=hashlib.sha256)


def _tag(keyed: hmac.HMAC, seq: int, body: bytes) -> bytes:
    h = keyed.copy()
    h.update(seq.to_bytes(8, "little"))
    h.update(body)
    return h.digest()[:TAG_BYTES]


@dataclass
class Signer:
    """Signs one topic's messages of one publisher, in publishing order."""

    key: bytes  # the run key
    topic: str
    count: int = 0  # messages signed so far
    stream: int = field(default_factory=lambda: secrets.randbits(SEQ_HEX * 4 - COUNT_BITS))
    _topic_key: hmac.HMAC = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._topic_key = _keyed(topic_key(self.key, self.topic))

    def _next(self) -> int:
        self.count += 1
        return self.stream << COUNT_BITS | self.count

    def sign(self, cdr: bytes) -> bytes:
        """`cdr` (a message with a Header first and an empty frame_id) with its signature as
        frame_id."""
        if cdr[FRAME_ID_LENGTH_AT:FRAME_ID_AT] != EMPTY_LENGTH or cdr[:2] != CDR_LE:
            raise ValueError(
                f"{self.topic}: only a little-endian message with an empty header.frame_id is "
                "signed (the signature takes its place)"
            )
        body = cdr[:FRAME_ID_LENGTH_AT] + SIGNED_LENGTH + _PLACEHOLDER_BYTES + cdr[FRAME_ID_AT:]
        # Fast DDS pads a payload to a multiple of 4 bytes between processes (and says so
        # nowhere): the tag covers the padded message, as every receiver gets it
        body += bytes(-len(body) % 4)
        seq = self._next()
        signature = b"%016x" % seq + _tag(self._topic_key, seq, body).hex().encode()
        return body[:FRAME_ID_AT] + signature + body[FRAME_ID_AT + SIGNATURE_CHARS :]

    def sign_text(self, text: str) -> str:
        """A text message with its signature as the last word."""
        seq = self._next()
        tag = _tag(self._topic_key, seq, text.encode())
        return f"{text}{TEXT_MARK}{seq:016x}{tag.hex()}"


@dataclass
class ReplayWindow:
    """The sequence numbers taken so far: the newest and a bitmap of the WINDOW before it."""

    size: int = WINDOW
    newest: int = 0
    _seen: int = 0  # bit k: newest - k was taken
    _mask: int = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._mask = (1 << self.size) - 1

    def check(self, seq: int) -> bool:
        """Whether `seq` is new (then it counts as taken), as RFC 4303 section 3.4.3."""
        if seq <= 0:
            return False
        if seq > self.newest:
            shift = seq - self.newest
            self._seen = ((self._seen << shift) | 1) & self._mask
            self.newest = seq
            return True
        age = self.newest - seq
        if age >= self.size or self._seen >> age & 1:
            return False
        self._seen |= 1 << age
        return True


@dataclass
class Verifier:
    """Checks one topic's incoming messages; counts what it refused, by reason."""

    key: bytes
    topic: str
    windows: dict[int, ReplayWindow] = field(default_factory=dict)  # stream -> its window
    refused: dict[str, int] = field(default_factory=dict)
    last: str = ""  # the reason of the last refusal
    _topic_key: hmac.HMAC = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._topic_key = _keyed(topic_key(self.key, self.topic))

    def verify(self, data: bytes) -> bytes | None:
        """The message as its node made it (empty frame_id) when it is the run's, new and
        unaltered; None (and counted) otherwise."""
        if (
            data[FRAME_ID_LENGTH_AT:FRAME_ID_AT] != SIGNED_LENGTH
            or data[:2] != CDR_LE
            or len(data) < FRAME_ID_AT + SIGNATURE_CHARS + 1
        ):
            return self._refuse(UNSIGNED)
        signature = data[FRAME_ID_AT : FRAME_ID_AT + SIGNATURE_CHARS]
        rest = data[FRAME_ID_AT + SIGNATURE_CHARS :]
        seq = _hex_int(signature[:SEQ_HEX])
        if seq is None:
            return self._refuse(UNSIGNED)
        body = data[:FRAME_ID_AT] + _PLACEHOLDER_BYTES + rest
        expected = _tag(self._topic_key, seq, body).hex().encode()
        if not hmac.compare_digest(expected, signature[SEQ_HEX:]):
            return self._refuse(BAD_TAG)
        if not self._new(seq):
            return self._refuse(REPLAYED)
        return data[:FRAME_ID_LENGTH_AT] + EMPTY_LENGTH + rest

    def verify_text(self, text: str) -> str | None:
        """The text without its signature, when it is the run's, new and unaltered."""
        body, mark, signature = text.rpartition(TEXT_MARK)
        seq = _hex_int(signature[:SEQ_HEX].encode()) if mark else None
        if seq is None or len(signature) != SIGNATURE_CHARS:
            return self._refuse(UNSIGNED)
        expected = _tag(self._topic_key, seq, body.encode()).hex()
        if not hmac.compare_digest(expected, signature[SEQ_HEX:]):
            return self._refuse(BAD_TAG)
        if not self._new(seq):
            return self._refuse(REPLAYED)
        return body

    def _new(self, seq: int) -> bool:
        stream = seq >> COUNT_BITS
        window = self.windows.get(stream)
        if window is None:
            if len(self.windows) >= MAX_STREAMS:
                return False
            window = self.windows[stream] = ReplayWindow()
        return window.check(seq & ((1 << COUNT_BITS) - 1))

    def _refuse(self, reason: str) -> None:
        self.refused[reason] = self.refused.get(reason, 0) + 1
        self.last = reason
        return None


def _hex_int(digits: bytes) -> int | None:
    # int() alone would take "+", "_" and spaces as well
    if len(digits) != SEQ_HEX or digits.strip(b"0123456789abcdef"):
        return None
    return int(digits, 16)


class RunAuth:
    """A node's signers and verifiers, one per topic, from the run key (None: the node runs
    outside `feed-twin run` or beside an external NC, and neither signs nor checks)."""

    def __init__(self, key: bytes | None) -> None:
        self.key = key
        self._signers: dict[str, Signer] = {}
        self._verifiers: dict[str, Verifier] = {}

    @classmethod
    def from_environ(cls, environ: Mapping[str, str]) -> RunAuth:
        return cls(key_from_environ(environ))

    @property
    def enabled(self) -> bool:
        return self.key is not None

    def sign(self, topic: str, cdr: bytes) -> bytes:
        return cdr if self.key is None else self._signer(topic).sign(cdr)

    def verify(self, topic: str, data: bytes) -> bytes | None:
        """The message as the run's layouts decode it, or None when it is not the run's."""
        if self.key is None:
            return data
        return self.verifier(topic).verify(data)

    def sign_text(self, topic: str, text: str) -> str:
        return text if self.key is None else self._signer(topic).sign_text(text)

    def _signer(self, topic: str) -> Signer:
        signer = self._signers.get(topic)
        if signer is None:
            if self.key is None:
                raise ValueError(f"{topic}: no run key, nothing to sign with")
            signer = self._signers[topic] = Signer(self.key, topic)
        return signer

    def verify_text(self, topic: str, text: str) -> str | None:
        if self.key is None:
            return text
        return self.verifier(topic).verify_text(text)

    def verifier(self, topic: str) -> Verifier:
        verifier = self._verifiers.get(topic)
        if verifier is None:
            if self.key is None:
                raise ValueError(f"{topic}: no run key, nothing to verify with")
            verifier = self._verifiers[topic] = Verifier(self.key, topic)
        return verifier

    def last_refusal(self, topic: str) -> str:
        """Why the last message on `topic` was refused (the reason counted most recently)."""
        verifier = self._verifiers.get(topic)
        return verifier.last if verifier is not None else ""
