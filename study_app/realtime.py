"""Keeping the presentation loop on time: no garbage-collector pauses during a trial and the
best scheduling the operating system grants a normal user.

Measured on a loaded 2-vCPU machine (benchmarks/bench_player.py, see README): a flip interval
longer than 1.5 refreshes came from the main thread being switched out while Mesa's
rasteriser threads and the X server ran, and now and then from a garbage-collector pass
traversing the frames' objects. So, during a trial:

- :func:`presentation_guard` moves every object alive after the warm-up into the collector's
  permanent generation (``gc.freeze``) and switches automatic collection off until the trial
  ends (a trial allocates only small, short-lived objects; they are collected right after);
- :func:`raise_priority` asks, once, for a higher priority where no admin rights are needed
  (Windows: HIGH_PRIORITY_CLASS and a 1 ms timer; Linux: a lower nice value, granted to
  root or within RLIMIT_NICE, and a 1 us timer slack for the clock pacer; macOS: nothing
  without privileges). What was granted is recorded with the display information.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import logging
import os
import sys
from collections.abc import Iterator

log = logging.getLogger(__name__)


@contextlib.contextmanager
def presentation_guard() -> Iterator[None]:
    """No automatic garbage collection while a trial is on screen."""
    was_enabled = gc.isenabled()
    gc.collect(0)
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if was_enabled:
            gc.enable()
        gc.collect(0)


@contextlib.contextmanager
def unguarded() -> Iterator[None]:
    """The loop without any collector control (for comparison in the benchmark)."""
    yield


def _linux() -> str:
    parts = []
    for nice in (-10, -5, -1):
        try:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
            parts.append(f"nice {nice}")
            break
        except (PermissionError, OSError):
            continue
    else:
        parts.append("nice unchanged (no permission)")
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_timerslack = 29
        if libc.prctl(pr_set_timerslack, 1000, 0, 0, 0) == 0:
            parts.append("timer slack 1 us")
    except (OSError, AttributeError):
        pass
    return ", ".join(parts)


def _windows() -> str:
    parts = []
    try:
        kernel32 = ctypes.windll.kernel32  # type: ignore[attr-defined]
        high_priority_class = 0x80
        if kernel32.SetPriorityClass(kernel32.GetCurrentProcess(), high_priority_class):
            parts.append("high priority class")
        winmm = ctypes.windll.winmm  # type: ignore[attr-defined]
        if winmm.timeBeginPeriod(1) == 0:
            parts.append("1 ms timer")
    except (OSError, AttributeError):
        pass
    return ", ".join(parts) or "unchanged"


def raise_priority() -> str:
    """Ask for better scheduling where no admin rights are needed; says what was granted."""
    if sys.platform.startswith("linux"):
        granted = _linux()
    elif sys.platform == "win32":
        granted = _windows()
    else:
        granted = "unchanged (not possible without privileges on this system)"
    log.info("scheduling: %s", granted)
    return granted
