"""A recording cut at any byte keeps every complete chunk, indexed in place (no second copy):
checked at every offset of a small bag with the mcap library's own reader, with rosbags at a
few, and on a full file system, where nothing flushed is lost."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import make_reader

from feed_twin.io import msg_types
from feed_twin.io.bag import BagWriter
from feed_twin.io.bag.index import CutBagError, index_in_place, scan
from feed_twin.io.cdr import FlatCodec

CODEC = FlatCodec(msg_types.FLOAT64)
PER_CHUNK = 3
CHUNKS = 3


def _small_bag(directory: Path) -> tuple[bytes, list[int], list[bytes]]:
    """(the MCAP file's bytes, each chunk's end offset, the messages' data in order)."""
    written = []
    with BagWriter(directory / "b", flush_period_s=None) as bag:
        bag.add_topic("/a", msg_types.FLOAT64)
        bag.add_topic("/b", msg_types.FLOAT64)
        for k in range(PER_CHUNK * CHUNKS):
            data = CODEC.encode_map({"data": float(k)})
            bag.write("/a" if k % 2 else "/b", data, log_time_ns=1_000 + k)
            written.append(data)
            if k % PER_CHUNK == PER_CHUNK - 1:
                bag.flush()  # one chunk per flush, as the recorder's flush thread makes them
    full = (directory / "b" / "b_0.mcap").read_bytes()
    with open(directory / "b" / "b_0.mcap", "rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    ends = [c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes]
    assert len(ends) == CHUNKS
    return full, ends, written


def _read(path: Path) -> list[bytes]:
    with open(path, "rb") as handle:
        return [m.data for _, _, m in make_reader(handle).iter_messages(log_time_order=False)]


@pytest.fixture
def work() -> Iterator[Path]:
    """A RAM directory where there is one (fsync is free there), else a temporary one."""
    base = Path("/dev/shm") if Path("/dev/shm").is_dir() else Path("/tmp")
    path = base / f"feed_twin_bag_index_{os.getpid()}"
    path.mkdir()
    yield path
    shutil.rmtree(path, ignore_errors=True)


def test_a_bag_cut_at_every_offset_keeps_every_complete_chunk(work):
    full, ends, written = _small_bag(work)
    cut = work / "cut.mcap"
    for offset in range(len(full) + 1):
        cut.write_bytes(full[:offset])
        kept = PER_CHUNK * sum(end <= offset for end in ends)
        if kept == 0:
            with pytest.raises(CutBagError, match=r"nothing recoverable"):
                index_in_place(cut)
            continue
        result, _ = index_in_place(cut)
        assert result.messages == kept, offset
        assert _read(cut) == written[:kept], offset
        assert result.finished == (offset == len(full))
        if not result.finished:
            assert result.kept_bytes + result.dropped_bytes == offset


def test_an_indexed_bag_reads_with_rosbags_and_indexing_again_changes_nothing(work):
    from rosbags.highlevel import AnyReader

    full, ends, written = _small_bag(work)
    bag = work / "b"
    mcap = bag / "b_0.mcap"
    (bag / "metadata.yaml").unlink()
    for offset in (ends[1] + 7, ends[2] - 1, ends[1]):
        mcap.write_bytes(full[:offset])
        index_in_place(mcap)
        size = mcap.stat().st_size
        assert index_in_place(mcap)[0].finished and mcap.stat().st_size == size
        kept = 2 * PER_CHUNK
        # rosbags needs metadata.yaml for a bag directory; the MCAP file alone it reads too
        with AnyReader([mcap]) as reader:
            got = [raw for _, _, raw in reader.messages()]
        assert got == written[:kept]


NO_ROOM = """
import resource, signal, sys
from pathlib import Path
from feed_twin.io.bag.index import CutBagError, index_in_place
path = Path(sys.argv[1])
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (path.stat().st_size, resource.RLIM_INFINITY))
try:
    index_in_place(path)
except CutBagError as exc:
    print(exc)
"""


def test_without_room_for_the_index_nothing_flushed_is_lost(work):
    """No byte may be added (a full disk; here a file size limit, which fails the same write
    deterministically): the file stays as flushed, and indexes once there is room."""
    full, ends, written = _small_bag(work)
    mcap = work / "cut.mcap"
    mcap.write_bytes(full[: ends[1]])  # cut at a chunk's end: nothing to drop
    said = subprocess.run(
        [sys.executable, "-c", NO_ROOM, str(mcap)], capture_output=True, text=True, timeout=60
    )
    assert re.fullmatch(
        re.escape(f"{mcap}: no room to index the recording in place (File too large; ")
        + r"\d+ bytes needed\): its 2 complete chunks \(6 messages\) are kept as they are; "
        r"free some space and run `feed-twin bag recover` on it",
        said.stdout.strip(),
    ), said.stderr
    assert mcap.read_bytes() == full[: ends[1]]
    assert scan(mcap).message_count == 2 * PER_CHUNK
    assert index_in_place(mcap)[0].messages == 2 * PER_CHUNK  # room again
    assert _read(mcap) == written[: 2 * PER_CHUNK]
    assert sorted(p.name for p in work.iterdir()) == ["b", "cut.mcap"]  # no second copy
