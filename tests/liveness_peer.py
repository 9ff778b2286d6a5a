"""A bare feed_twin node for the liveness tests: it beats, watches its peers and, whenever the
file `<flag>` appears, removes it and holds its own loop for `hold_s` while its beat thread goes
on (a wait it knows of, `FeedTwinNode.waiting`, when the file says "waiting").

    python tests/liveness_peer.py ROLE PEER[,PEER...] FLAG HOLD_S
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

from feed_twin.ros.dds import init_context
from feed_twin.ros.runtime import FeedTwinNode, NodeOptions, spin_nodes


class HoldingNode(FeedTwinNode):
    def __init__(self, role: str, peers: tuple[str, ...], flag: Path, hold_s: float, context):
        super().__init__(role, NodeOptions(machine="lv", axis="x", peers=peers), context=context)
        self.flag = flag
        self.hold_s = hold_s
        self.said_seen = False

    def poll(self) -> float | None:
        if not self.said_seen and self.peers_alive():
            self.said_seen = True
            print("SEEN", flush=True)
        if self.flag.exists():
            known = self.flag.read_text() == "waiting"
            self.flag.unlink()
            with self.waiting() if known else contextlib.nullcontext():
                time.sleep(self.hold_s)  # the loop stops; the beat thread (no GIL held) goes on
            print("HELD", flush=True)
        return 0.02


def main() -> int:
    role, peers, flag, hold_s = sys.argv[1:5]
    context = init_context()
    node = HoldingNode(role, tuple(peers.split(",")), Path(flag), float(hold_s), context)
    node.start_heartbeat()
    return spin_nodes([node], context)


if __name__ == "__main__":
    sys.exit(main())
