"""Two "computers" on one Linux host: network namespaces joined by a veth pair (needs root).

    with linked_namespaces("ft") as (a, b):
        subprocess.run(a.command(["python", "-m", ...]), env=a.env(base_env))

Each side has only its loopback and its end of the link (`address`, /24), so DDS traffic between
the sides crosses the veth pair as it would cross a network, and each side's Fast DDS profile
(`dds.peers_profile`) limits discovery to that link. The namespaces are deleted on the way out,
also after an exception or a failed set-up (deleting a namespace removes its veth end, and with
it the pair).
"""

from __future__ import annotations

import contextlib
import os
import subprocess
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from feed_twin.ros.dds import peers_profile


@dataclass(frozen=True, kw_only=True)
class Side:
    namespace: str  # network namespace name
    address: str  # IPv4 address of its veth end
    profile: Path  # its Fast DDS profile file

    def command(self, argv: Sequence[str]) -> list[str]:
        """`argv` run inside this side's network namespace."""
        return ["ip", "netns", "exec", self.namespace, *argv]

    def env(self, base: dict[str, str]) -> dict[str, str]:
        """`base` with this side's Fast DDS profile (kept by the nodes, dds.dds_environment)
        and discovery beyond localhost."""
        return {
            **base,
            "FASTRTPS_DEFAULT_PROFILES_FILE": str(self.profile),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        }


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


@contextlib.contextmanager
def linked_namespaces(tag: str, directory: Path) -> Iterator[tuple[Side, Side]]:
    """Namespaces `<tag>a<pid>` and `<tag>b<pid>` with a veth pair between them; their profiles
    are written into `directory`."""
    pid = os.getpid()
    names = (f"{tag}a{pid}", f"{tag}b{pid}")
    links = (f"{tag}va{pid % 100000}", f"{tag}vb{pid % 100000}")  # at most 15 characters
    subnet = f"10.{200 + pid % 50}.{pid // 50 % 250}"
    addresses = (f"{subnet}.1", f"{subnet}.2")
    created: list[str] = []
    try:
        for name in names:
            _ip("netns", "add", name)
            created.append(name)
        _ip("link", "add", links[0], "type", "veth", "peer", "name", links[1])
        sides = []
        for name, link, address in zip(names, links, addresses, strict=True):
            _ip("link", "set", link, "netns", name)
            _ip("-n", name, "addr", "add", f"{address}/24", "dev", link)
            _ip("-n", name, "link", "set", link, "up")
            _ip("-n", name, "link", "set", "lo", "up")
            profile = directory / f"fastdds_{name}.xml"
            profile.write_text(peers_profile(address, addresses))
            sides.append(Side(namespace=name, address=address, profile=profile))
        yield sides[0], sides[1]
    finally:
        for name in created:
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
        # a pair created before its ends moved into the namespaces lives in the root namespace
        subprocess.run(["ip", "link", "del", links[0]], capture_output=True, timeout=30)
