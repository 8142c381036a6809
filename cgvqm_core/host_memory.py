"""Freed host memory kept for reuse while a video is scored on a CPU.

Why: glibc gives blocks above its mmap threshold their own mapping, returned to the kernel
when freed, so every pass of the network that allocates such blocks gets fresh pages the
kernel must fault in and zero: a 30x512x512 CGVQM-2 pair on a 2-core EPYC took 152 thousand
page faults (on transparent huge pages) and 19.0 s, against 6 thousand and 17.4 s with
memory kept. While scoring, :func:`retained` raises the threshold to glibc's largest (32
MiB) and keeps freed memory in the heap (a high ``M_TRIM_THRESHOLD``); a pass's activations
reuse it when each stays under 32 MiB, which is what the CPU batch size aims for
(:func:`~cgvqm_core.patch_scorer.default_batch_size`). Larger blocks keep their own mapping:
putting them in the heap as well (``M_MMAP_MAX`` 0) was a little faster but fragmented it,
doubling the peak memory of a 1080p pair. On leaving, glibc's defaults come back and
``malloc_trim`` returns the kept memory.

Nothing changes on other C libraries, or where the process chose its own settings through
glibc's ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_`` variables.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

# glibc's mallopt parameters and their defaults
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
DEFAULT_TRIM_THRESHOLD = 128 * 1024
DEFAULT_MMAP_THRESHOLD = 128 * 1024
#: glibc's largest mmap threshold on 64-bit systems: blocks up to this size can be kept
MAX_KEPT_BLOCK = 32 * 2**20
KEEP_TRIM_THRESHOLD = 2**31 - 1  # mallopt takes an int: trim nothing below 2 GiB

_lock = threading.Lock()
_users = 0
_off = 0  # depth of disabled() blocks


def _glibc() -> ctypes.CDLL | None:
    """The process's glibc, or None (another C library, or the user tuned malloc)."""
    if any(k in os.environ for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - present only in glibc
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        libc.malloc_trim.argtypes = [ctypes.c_size_t]
    except (OSError, AttributeError):
        return None
    return libc


_LIBC = _glibc()


def available() -> bool:
    """Whether :func:`retained` changes anything in this process."""
    return _LIBC is not None


@contextmanager
def retained(enabled: bool = True) -> Iterator[None]:
    """Keep freed host memory for reuse for the duration (nested and threaded use share one
    setting: the last one out restores glibc's defaults and trims)."""
    global _users
    libc = _LIBC if enabled and not _off else None
    if libc is None:
        yield
        return
    with _lock:
        _users += 1
        if _users == 1:
            libc.mallopt(M_MMAP_THRESHOLD, MAX_KEPT_BLOCK)
            libc.mallopt(M_TRIM_THRESHOLD, KEEP_TRIM_THRESHOLD)
    try:
        yield
    finally:
        with _lock:
            _users -= 1
            if _users == 0:
                libc.mallopt(M_MMAP_THRESHOLD, DEFAULT_MMAP_THRESHOLD)
                libc.mallopt(M_TRIM_THRESHOLD, DEFAULT_TRIM_THRESHOLD)
                libc.malloc_trim(0)


@contextmanager
def disabled() -> Iterator[None]:
    """:func:`retained` changes nothing for the duration (to measure what it gains)."""
    global _off
    with _lock:
        _off += 1
    try:
        yield
    finally:
        with _lock:
            _off -= 1
