"""Compiling the C kernel with the system C compiler and loading it with ctypes.

    kernel = c_kernel_for_axis(axis)               # feed_twin.native.emit.CKernel
    model = CModel(compile_kernel(kernel))         # ctypes: run, states, set_param, ...
    rec = model.run(n, ref=ref)                    # rows named kernel.record_names

Flags: -O3 and IEEE arithmetic as numba's kernel has it (-ffp-contract=off: the compiler fuses
no multiply-add the source does not spell `fma`; no fast-math), -fwrapv (int64 wraps, as in
numba), and -march=native, as numba compiles for the CPU it runs on: `fma` is then one
instruction instead of a call into the C library (correctly rounded either way: the same
doubles), and AVX-512's 32 registers spill less. -fno-trapping-math (no FP exception ever traps
here) lets divisions by parameters leave the loop; -fno-tree-vectorize: the vectorised copies
are slower (docs/performance.md).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
from pathlib import Path

import numpy as np

from feed_twin.native.emit import CKernel, c_kernel
from feed_twin.sim.kernel import cache_dir

CC_PACKAGE = "gcc"  # Debian package of the system C compiler `cc`
FLAGS = (
    "-O3",
    "-ffp-contract=off",
    "-fwrapv",
    "-fno-math-errno",
    "-fno-trapping-math",
    "-fno-tree-vectorize",
    "-fPIC",
    "-std=gnu11",
)


class CompilerMissingError(RuntimeError):
    """No C compiler on the PATH."""


def find_cc(name: str = "cc") -> str:
    path = shutil.which(name)
    if path is None:
        raise CompilerMissingError(
            f"no C compiler: `{name}` is not on the PATH; install the Debian package "
            f"{CC_PACKAGE} (apt-get install {CC_PACKAGE})"
        )
    return path


def cpu_flags() -> tuple[str, ...]:
    """-march=native on x86-64 (numba too compiles for the CPU it runs on)."""
    return ("-march=native",) if platform.machine() in ("x86_64", "AMD64") else ()


def portable_flags() -> tuple[str, ...]:
    """For a binary that leaves this machine (the FMU): x86-64-v3 (AVX2 and FMA: Haswell, Zen
    and later) when this CPU has it, else the x86-64 baseline, whose `fma` is libm's (the same
    doubles, about half the speed)."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return ()
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return ()
    flags = set(next((ln for ln in text.splitlines() if ln.startswith("flags")), "").split())
    return ("-march=x86-64-v3",) if {"avx2", "fma", "bmi2", "movbe"} <= flags else ()


def write_sources(kernel: CKernel, directory: Path, stem: str = "feed_twin_axis") -> Path:
    """`<stem>.c` and `feed_twin_axis.h` in `directory`; returns the .c path."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "feed_twin_axis.h").write_text(kernel.header)
    c_path = directory / f"{stem}.c"
    c_path.write_text(kernel.source)
    return c_path


def compile_kernel(kernel: CKernel, *, cc: str = "cc", extra: tuple[str, ...] = ()) -> Path:
    """The shared library of `kernel`, compiled once per source and flags (cached on disk)."""
    compiler = find_cc(cc)
    flags = FLAGS + cpu_flags() + tuple(extra)
    digest = hashlib.sha256((kernel.source + kernel.header + " ".join(flags)).encode())
    directory = cache_dir() / "native" / digest.hexdigest()[:20]
    library = directory / "feed_twin_axis.so"
    if library.exists():
        return library
    c_path = write_sources(kernel, directory)
    tmp = directory / f"feed_twin_axis.tmp{os.getpid()}.so"  # parallel builds never share one
    run_cc(compiler, [*flags, "-shared"], [c_path], tmp)
    tmp.replace(library)
    return library


def run_cc(compiler: str, flags: list[str], sources: list[Path], output: Path) -> None:
    """Compile and link `sources` into `output`; the compiler's complaint on failure."""
    command = [compiler, *flags, "-o", str(output), *map(str, sources), "-lm"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"{sources[0]}: {compiler} failed:\n{result.stderr[-4000:]}")


def c_kernel_for_axis(axis, *, closed_loop: bool = True) -> CKernel:
    """The C kernel of a loaded axis configuration (feed_twin.sim.config.AxisConfig)."""
    controller = None
    if closed_loop:
        from feed_twin.control.layout import build_cascade

        controller = build_cascade(axis.controller)
    return c_kernel(
        axis.plant,
        base_period_s=axis.engine.base_period_s,
        controller=controller,
        substeps=axis.engine.substeps,
        seed=axis.engine.seed,
    )


_D = ctypes.POINTER(ctypes.c_double)


class CModel:
    """One instance of a compiled C kernel, through ctypes."""

    def __init__(self, library: Path, kernel: CKernel) -> None:
        lib = ctypes.CDLL(str(library))
        lib.ft_create.restype = ctypes.c_void_p
        lib.ft_free.argtypes = [ctypes.c_void_p]
        lib.ft_reset.argtypes = [ctypes.c_void_p]
        lib.ft_run.restype = ctypes.c_int64
        lib.ft_run.argtypes = [ctypes.c_void_p, ctypes.c_int64, _D, _D, _D, _D]
        lib.ft_set_states.argtypes = [ctypes.c_void_p, _D]
        lib.ft_set_param.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_double]
        lib.ft_set_ctrl_param.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_double]
        for name in ("ft_states", "ft_meas", "ft_out", "ft_ctrl_states", "ft_status", "ft_aux"):
            getattr(lib, name).restype = _D
            getattr(lib, name).argtypes = [ctypes.c_void_p]
        lib.ft_tick.restype = ctypes.c_int64
        lib.ft_tick.argtypes = [ctypes.c_void_p]
        self.lib, self.kernel = lib, kernel
        self.handle = lib.ft_create()
        if not self.handle:
            raise MemoryError("ft_create")

    def __del__(self) -> None:
        if getattr(self, "handle", None):
            self.lib.ft_free(self.handle)
            self.handle = None

    def reset(self) -> None:
        self.lib.ft_reset(self.handle)

    def set_param(self, name: str, value: float) -> None:
        code = self.lib.ft_set_param(self.handle, self.kernel.param_names.index(name), value)
        if code != 0:
            raise KeyError(name)

    def set_ctrl_param(self, name: str, value: float) -> None:
        code = self.lib.ft_set_ctrl_param(
            self.handle, self.kernel.ctrl_param_names.index(name), value
        )
        if code != 0:
            raise ValueError(f"controller parameter {name} = {value!r}: fixed in this kernel")

    def set_states(self, x: np.ndarray) -> None:
        x = np.ascontiguousarray(x, dtype=float)
        if x.shape != (len(self.kernel.state_names),):
            raise ValueError(f"states: shape {x.shape}, expected ({len(self.kernel.state_names)},)")
        self.lib.ft_set_states(self.handle, x.ctypes.data_as(_D))

    def run(self, n: int, *, ref=None, drive=None, ext=None, every: int = 1) -> np.ndarray:
        """n ticks with per-tick input rows (None: held); the recorded rows of every `every`-th
        tick (0: none), in chunks so that a long run does not hold every row at once."""
        arrays = [
            None if a is None else np.ascontiguousarray(a, dtype=float) for a in (ref, drive, ext)
        ]
        width = len(self.kernel.record_names)
        chunk = max(every, 1) * max(1, 8192 // max(every, 1))
        rows = []
        for start in range(0, n, chunk):
            m = min(chunk, n - start)
            rec = np.zeros((m, width)) if every else None
            ptrs = [None if a is None else a[start:].ctypes.data_as(_D) for a in arrays]
            done = self.lib.ft_run(
                self.handle, m, *ptrs, None if rec is None else rec.ctypes.data_as(_D)
            )
            if rec is not None:
                rows.append(rec[:done:every])
            if done < m:
                _, tick, state, value = self.status()
                raise RuntimeError(
                    f"state {self.kernel.state_names[int(state)]} ran away at tick {int(tick)} "
                    f"(value {value!r})"
                )
        return np.concatenate(rows) if rows else np.zeros((0, width))

    def _vector(self, name: str, size: int) -> np.ndarray:
        ptr = getattr(self.lib, name)(self.handle)
        return np.ctypeslib.as_array(ptr, shape=(size,)).copy()

    def states(self) -> np.ndarray:
        return self._vector("ft_states", len(self.kernel.state_names))

    def status(self) -> np.ndarray:
        return self._vector("ft_status", 4)

    def tick(self) -> int:
        """Ticks simulated since the last reset."""
        return int(self.lib.ft_tick(self.handle))
