"""Foreign messages: what a run's nodes refused, by topic, reason and publisher.

Every node of a run that takes messages (the controller, the sim, the recorder, the twin...)
checks each one (feed_twin.nodeset.auth) and drops what is not the run's own. A `ForeignLedger`
counts the drops per topic and reason and keeps the publishers the graph showed on that topic
that are not nodes of the run (rclpy gives a callback no publisher identity, so a message is
attributed to the foreign publishers of its topic; one that left before the graph was read is
"unknown"). At its end each node prints its ledger as a `FOREIGN {json}` log line; the runner
merges the lines of every node (`merge`: the largest count per topic and reason, as several
nodes hear the same messages, and every publisher) into the run's `foreign_messages`.

Pure: the ROS side passes topic names, reasons and described publishers in.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

LOG_PREFIX = "FOREIGN"
UNKNOWN_PUBLISHER = "unknown (not in the graph when it was read)"


@dataclass
class TopicLedger:
    reasons: dict[str, int] = field(default_factory=dict)  # reason -> messages dropped
    publishers: set[str] = field(default_factory=set)  # described foreign publishers

    @property
    def count(self) -> int:
        return sum(self.reasons.values())


@dataclass
class ForeignLedger:
    topics: dict[str, TopicLedger] = field(default_factory=dict)

    def refuse(self, topic: str, reason: str) -> int:
        """Count one dropped message; returns the topic's count so far."""
        entry = self.topics.setdefault(topic, TopicLedger())
        entry.reasons[reason] = entry.reasons.get(reason, 0) + 1
        return entry.count

    def name(self, topic: str, publisher: str) -> bool:
        """Attribute the topic's foreign messages to `publisher` too; True when it is new."""
        entry = self.topics.setdefault(topic, TopicLedger())
        if publisher in entry.publishers:
            return False
        entry.publishers.add(publisher)
        return True

    @property
    def count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def as_dict(self) -> dict[str, dict]:
        """`foreign_messages` of the run's JSON: topic -> messages, reasons, publishers (only
        topics with dropped messages or foreign publishers)."""
        return {
            topic: {
                "messages": entry.count,
                "reasons": dict(sorted(entry.reasons.items())),
                "publishers": sorted(entry.publishers)
                or ([UNKNOWN_PUBLISHER] if entry.count else []),
            }
            for topic, entry in sorted(self.topics.items())
            if entry.count or entry.publishers
        }

    def log_line(self) -> str:
        return f"{LOG_PREFIX} {json.dumps(self.as_dict(), sort_keys=True)}"

    def lines(self) -> list[str]:
        """The run's own output: one line per topic, e.g. `foreign messages: 3120 on
        /cnc/x/state (bad tag 3120), dropped; from node '/intruder' (publisher gid ...)`."""
        out = []
        for topic, entry in self.as_dict().items():
            why = ", ".join(f"{r} {n}" for r, n in entry["reasons"].items())
            who = "; ".join(entry["publishers"])
            what = f"{entry['messages']} on {topic} ({why}), dropped" if why else f"on {topic}"
            out.append(f"foreign messages: {what}; from {who}")
        return out


def foreign_publisher_text(topic: str, publisher: str) -> str:
    """The log and health line of a node that names a foreign publisher of `topic`."""
    return f"foreign publisher on {topic}: {publisher}; its messages are refused"


def merge(records: Iterable[Mapping[str, Mapping]]) -> ForeignLedger:
    """One ledger from the nodes' `as_dict()` records (module docstring)."""
    ledger = ForeignLedger()
    for record in records:
        for topic, entry in record.items():
            merged = ledger.topics.setdefault(topic, TopicLedger())
            for reason, n in dict(entry.get("reasons", {})).items():
                merged.reasons[reason] = max(merged.reasons.get(reason, 0), int(n))
            merged.publishers.update(
                p for p in entry.get("publishers", ()) if p != UNKNOWN_PUBLISHER
            )
    return ledger


def parse_log(text: str) -> list[dict]:
    """The `FOREIGN {json}` records of a node's log text (malformed ones are skipped)."""
    records = []
    for line in text.splitlines():
        if line.startswith(f"{LOG_PREFIX} "):
            try:
                record = json.loads(line[len(LOG_PREFIX) + 1 :])
            except ValueError:
                continue
            if isinstance(record, dict):
                records.append(record)
    return records
