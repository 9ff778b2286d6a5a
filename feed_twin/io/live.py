"""A run's dashboards live in a browser: Rerun's gRPC server and web viewer in a child process.

    viewer = start_live(args)          # --live, --live-addr, --live-port (add_live_options)
    ... Dashboard(rrd_path=..., live_url=viewer.grpc_url) ...
    linger(viewer, args.live_linger)   # keeps serving after the run: Ctrl-C or S seconds

The viewer listens on `--live-addr` (127.0.0.1 unless asked: the viewer has no authentication,
so another address is said in a warning), the web page on `--live-port` and the gRPC server the
page connects to on the port after it (or free ports when no port is given). The page's URL
names the gRPC server by the address a browser can reach: the host's name for 0.0.0.0.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

from feed_twin.io.dashboard import APPLICATION_ID, rerun_binary

LOOPBACK = "127.0.0.1"


def add_live_options(parser: argparse.ArgumentParser) -> None:
    """`--live`, `--live-addr`, `--live-port`, `--live-linger` for a command that runs a job."""
    parser.add_argument(
        "--live", action="store_true",
        help="serve the dashboard live in a browser (Rerun's web viewer); the URL is printed",
    )  # fmt: skip
    parser.add_argument(
        "--live-addr", default=LOOPBACK, metavar="ADDR",
        help=f"address the live viewer listens on (default {LOOPBACK}; 0.0.0.0: every interface, "
        "with a warning: the viewer has no authentication)",
    )  # fmt: skip
    parser.add_argument(
        "--live-port", type=int, default=None, metavar="PORT",
        help="port of the live web page (the gRPC server takes PORT + 1; default: free ports)",
    )  # fmt: skip
    parser.add_argument(
        "--live-linger", type=float, default=None, metavar="S",
        help="[s] keep serving the live viewer this long after the run (default: until Ctrl-C)",
    )  # fmt: skip


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


class LiveViewer:
    """Rerun's gRPC server and web viewer in a child process, on `host` (module docstring)."""

    def __init__(
        self,
        *,
        host: str = LOOPBACK,
        web_port: int | None = None,
        grpc_port: int | None = None,
        memory_limit: str = "1GiB",
        startup_timeout_s: float = 15.0,
    ) -> None:
        self.host = host
        self.web_port = web_port or _free_port(host)
        self.grpc_port = grpc_port or (self.web_port + 1 if web_port else _free_port(host))
        cmd = [
            str(rerun_binary()), "--serve-web", "--bind", host, "--port", str(self.grpc_port),
            "--web-viewer-port", str(self.web_port), "--server-memory-limit", memory_limit,
        ]  # fmt: skip
        self._proc = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env={**os.environ, "RERUN_ANALYTICS": "false"},
        )
        deadline = time.monotonic() + startup_timeout_s
        while not (self._listening(self.grpc_port) and self._listening(self.web_port)):
            if self._proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(
                    f"the Rerun viewer did not start listening on {host}:{self.grpc_port} and "
                    f":{self.web_port} within {startup_timeout_s} s (ports in use?)"
                )
            time.sleep(0.05)

    @property
    def reachable_host(self) -> str:
        """The address a browser uses: the host's name when listening on every interface."""
        return socket.gethostname() if self.host in ("0.0.0.0", "::") else self.host

    def _listening(self, port: int) -> bool:
        probe = LOOPBACK if self.host in ("0.0.0.0", "::") else self.host
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            return s.connect_ex((probe, port)) == 0

    @property
    def grpc_url(self) -> str:
        """Where the run's recording streams send (always this machine)."""
        probe = LOOPBACK if self.host in ("0.0.0.0", "::") else self.host
        return f"rerun+http://{probe}:{self.grpc_port}/proxy"

    @property
    def web_url(self) -> str:
        source = f"rerun+http://{self.reachable_host}:{self.grpc_port}/proxy"
        return f"http://{self.reachable_host}:{self.web_port}/?url={quote(source, safe='')}"

    def running(self) -> bool:
        return self._proc.poll() is None

    def stop(self) -> None:
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(timeout=5.0)


def start_live(args: argparse.Namespace) -> LiveViewer | None:
    """The viewer `--live` asks for (None without it); prints its URL and, for an address that
    is not loopback, the warning."""
    if not getattr(args, "live", False):
        return None
    if args.live_port is not None and not 1 <= args.live_port <= 65534:
        raise ValueError(f"--live-port {args.live_port}: must lie in [1, 65534]")
    if args.live_linger is not None and args.live_linger < 0:
        raise ValueError(f"--live-linger {args.live_linger:g}: must be >= 0 s")
    viewer = LiveViewer(host=args.live_addr, web_port=args.live_port)
    if not is_loopback(args.live_addr):
        print(
            f"warning: the live viewer listens on {args.live_addr} (ports {viewer.web_port}, "
            f"{viewer.grpc_port}), not on loopback: whoever reaches them sees the run; the "
            "viewer has no authentication",
            file=sys.stderr,
        )
    print(f"live: {viewer.web_url}", flush=True)
    return viewer


def linger(viewer: LiveViewer | None, seconds: float | None) -> None:
    """Keep serving after the run: `seconds`, or until Ctrl-C when None; then stop."""
    if viewer is None:
        return
    try:
        if seconds is None:
            print(f"live: still serving {viewer.web_url} (Ctrl-C to stop)", flush=True)
        deadline = math.inf if seconds is None else time.monotonic() + seconds
        while viewer.running() and time.monotonic() < deadline:
            time.sleep(min(0.2, max(deadline - time.monotonic(), 0.0)))
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()


def show_recording(viewer: LiveViewer | None, rrd: str | Path) -> None:
    """Send a finished recording (a run that writes its dashboard at the end) to the viewer."""
    if viewer is None:
        return
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.set_sinks(rr.GrpcSink(url=viewer.grpc_url))
    rec.log_file_from_path(Path(rrd))
    rec.flush()
