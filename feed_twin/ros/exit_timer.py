"""A deadline that ends the process with a given exit code even while a C call holds the GIL.

A node process's DDS teardown can hang in two ways: blocking with the GIL released (deleting a
reliable writer whose reader was killed), which a Python `threading.Timer` ends, and spinning
inside rclpy's events executor with the GIL held while a DDS thread waits for the GIL to finish a
listener callback, which no Python thread can interrupt. `exit_after` arms a POSIX timer
(timer_create with SIGEV_THREAD) whose notification, run by libc on a thread of its own, is
`_exit` itself with the code as its argument: no Python code, no GIL.

Linux only (glibc >= 2.34 has timer_create in libc; older ones in librt).
"""

from __future__ import annotations

import ctypes
import ctypes.util

_CLOCK_MONOTONIC = 1
_SIGEV_THREAD = 2


class _SigEvent(ctypes.Structure):
    # struct sigevent on Linux (64 bytes): the value handed to the notify function (union
    # sigval: its int member is the first bytes), signal number, notify kind, the thread
    # notification's function and attributes, padding to the kernel's size
    _fields_ = (
        ("sigev_value", ctypes.c_void_p),
        ("sigev_signo", ctypes.c_int),
        ("sigev_notify", ctypes.c_int),
        ("sigev_notify_function", ctypes.c_void_p),
        ("sigev_notify_attributes", ctypes.c_void_p),
        ("_pad", ctypes.c_byte * 32),
    )


class _TimeSpec(ctypes.Structure):
    _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))


class _ITimerSpec(ctypes.Structure):
    _fields_ = (("it_interval", _TimeSpec), ("it_value", _TimeSpec))


def _libraries() -> tuple[ctypes.CDLL, ctypes.CDLL]:
    """libc (for _exit) and the library with timer_create (libc, or librt before glibc 2.34)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    if hasattr(libc, "timer_create"):
        return libc, libc
    rt = ctypes.util.find_library("rt")
    if rt is not None:
        timers = ctypes.CDLL(rt, use_errno=True)
        if hasattr(timers, "timer_create"):
            return libc, timers
    raise OSError("no timer_create in libc or librt (POSIX timers need Linux)")


def exit_after(delay_s: float, code: int) -> None:
    """End the process with `code` (no cleanup, no output) `delay_s` seconds from now.

    OSError if the timer cannot be armed. The timer is never disarmed: call this only once the
    process has nothing left to do but leave."""
    if not delay_s > 0.0:
        raise ValueError(f"delay_s = {delay_s!r}: must be > 0")
    if not 0 <= code <= 255:
        raise ValueError(f"code = {code!r}: must lie in [0, 255]")
    libc, timers = _libraries()
    exit_function = ctypes.cast(libc._exit, ctypes.c_void_p).value
    event = _SigEvent(
        sigev_value=code, sigev_notify=_SIGEV_THREAD, sigev_notify_function=exit_function
    )
    timer = ctypes.c_void_p()
    if timers.timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
        raise OSError(ctypes.get_errno(), "timer_create failed")
    seconds = int(delay_s)
    spec = _ITimerSpec(it_value=_TimeSpec(seconds, int(round((delay_s - seconds) * 1e9))))
    if timers.timer_settime(timer, 0, ctypes.byref(spec), None) != 0:
        raise OSError(ctypes.get_errno(), "timer_settime failed")
