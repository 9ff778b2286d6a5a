"""Messages per topic of a bag, counted by the mcap library's own reader.

A second opinion on feed_twin's BagReader and on the metadata a recorder wrote: the run
summaries' counts are checked against it (tests/test_linuxcnc_shadow.py,
benchmarks/linuxcnc_load.py).
"""

from __future__ import annotations

from pathlib import Path


def mcap_counts(bag: Path) -> dict[str, int]:
    """Messages per topic in every `*.mcap` file of the bag directory `bag`."""
    from mcap.reader import make_reader

    counts: dict[str, int] = {}
    for path in sorted(Path(bag).glob("*.mcap")):
        with path.open("rb") as f:
            for _, channel, _ in make_reader(f).iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts
