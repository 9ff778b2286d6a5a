"""Where the C kernel's time goes: a per-law profile of axis_default's tick.

The C kernel (feed_twin.native) of config/axis_default.yaml, compiled with the flags of
feed_twin.native.build plus -g, runs the 1 s trapezoidal move of benchmarks/model_speed.py
REPEATS times in a small C driver under `perf record` (Debian package linux-perf). Every
function is inlined into `ft_run`, so each sample's address is mapped back through the debug
information's inline chain (binutils' addr2line -i): `self` is the share of samples whose
innermost source function is that law, `inclusive` the share in which it is anywhere on the
chain (kernel.integrate_tick: the RK4 tick, four derivative evaluations; generated_tick: noise,
sensors, the delay ring and the controller's cascade_tick).

Figures (last printed line, one JSON object): ns_per_tick (best of the driver's repeats in
thread CPU time, which other jobs on shared cores do not inflate), samples, self and inclusive
(percent, the TOP largest each).

    .venv/bin/python benchmarks/native_profile.py
"""

from __future__ import annotations

import collections
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from feed_twin.native.build import FLAGS, c_kernel_for_axis, cpu_flags, find_cc, write_sources
from feed_twin.sim.config import load_axis_config

sys.path.insert(0, str(Path(__file__).resolve().parent))
from model_speed import AXIS, trapezoid  # noqa: E402

REPEATS = 300
TOP = 25

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "feed_twin_axis.h"

int main(int argc, char **argv)
{
    long n = atol(argv[2]), repeats = atol(argv[3]);
    double *ref = malloc(sizeof(double) * n * FT_REF_SIZE);
    FILE *f = fopen(argv[1], "rb");
    if (!f || fread(ref, sizeof(double), n * FT_REF_SIZE, f) != (size_t)(n * FT_REF_SIZE)) return 2;
    fclose(f);
    ft_model *m = ft_create();
    double best = 1e30;
    for (long r = 0; r < repeats; ++r) {
        struct timespec a, b;
        ft_reset(m);
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &a);
        if (ft_run(m, n, ref, 0, 0, 0) != n) return 3;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &b);
        double t = (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
        if (t < best) best = t;
    }
    printf("%.3f\n", best * 1e9 / (double)n);
    return 0;
}
"""


def tool(name: str, package: str) -> str:
    path = shutil.which(name)
    if path is None:
        raise SystemExit(f"`{name}` is not on the PATH; install the Debian package {package}")
    return path


def readable(function: str) -> str:
    """`ft_feed_twin_kernel_<hash>_rhs_tuple` -> `kernel.rhs_tuple`, `ft_pmsm_pmsm_dq` ->
    `pmsm_pmsm_dq`."""
    return re.sub(r"^ft_feed_twin_kernel_[0-9a-f]+_", "kernel.", function).removeprefix("ft_")


def inline_chains(exe: Path, addresses: list[int]) -> dict[int, list[str]]:
    """Each address's functions, innermost first, from the debug information."""
    text = subprocess.run(
        [tool("addr2line", "binutils"), "-e", str(exe), "-i", "-f", "-a"],
        input="\n".join(hex(a) for a in addresses),
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    chains: dict[int, list[str]] = {}
    current = None
    i = 0
    while i < len(text):
        if text[i].startswith("0x"):
            current = int(text[i], 16)
            chains[current] = []
            i += 1
        else:
            assert current is not None, f"perf's chains begin with an address, not {text[0]!r}"
            chains[current].append(readable(text[i]))
            i += 2  # the function's line, then its file:line
    return chains


def main() -> int:
    perf = tool("perf", "linux-perf")
    axis = load_axis_config(AXIS)
    kernel = c_kernel_for_axis(axis)
    n = round(1.0 / axis.engine.base_period_s)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        c_path = write_sources(kernel, work)
        (work / "driver.c").write_text(DRIVER)
        trapezoid(n, axis.engine.base_period_s).tofile(work / "ref.bin")
        exe = work / "profile"
        flags = [f for f in FLAGS + cpu_flags() if f != "-fPIC"] + ["-g", "-no-pie"]
        subprocess.run(
            [
                find_cc(),
                *flags,
                f"-I{work}",
                str(c_path),
                str(work / "driver.c"),
                "-o",
                str(exe),
                "-lm",
            ],
            check=True,
        )
        run = [str(exe), str(work / "ref.bin"), str(n), str(REPEATS)]
        data = work / "perf.data"
        record = subprocess.run(
            [perf, "record", "-q", "-o", str(data), "--", *run],
            capture_output=True,
            text=True,
            check=True,
        )
        ns_per_tick = float(record.stdout.split()[-1])
        script = subprocess.run(
            [perf, "script", "-i", str(data), "-F", "ip,sym"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        samples = collections.Counter(
            int(fields[0], 16)
            for fields in (line.split() for line in script.splitlines())
            if len(fields) == 2 and fields[1] == "ft_run"
        )
        chains = inline_chains(exe, sorted(samples))
    total = sum(samples.values())
    own: collections.Counter[str] = collections.Counter()
    inclusive: collections.Counter[str] = collections.Counter()
    for address, count in samples.items():
        chain = chains.get(address) or ["ft_run"]
        own[chain[0]] += count
        for function in set(chain):
            inclusive[function] += count
    figures = {
        "ns_per_tick": ns_per_tick,
        "samples": total,
        "self": {f: round(100 * c / total, 1) for f, c in own.most_common(TOP)},
        "inclusive": {f: round(100 * c / total, 1) for f, c in inclusive.most_common(TOP)},
    }
    print(f"{ns_per_tick:.1f} ns per tick (best of {REPEATS}, thread CPU time), {total} samples")
    for name, share in figures["inclusive"].items():
        print(f"  {share:5.1f} % incl. {figures['self'].get(name, 0.0):5.1f} % self  {name}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
