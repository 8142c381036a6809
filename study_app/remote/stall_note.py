"""Says on the download bar that no data has come for a while.

A bar stops moving when the connection stalls, and tqdm keeps showing the last speed it
measured, so a participant reads "1.2 MB/s" over a download that has not moved for a
minute. A watcher thread notes the time of the last data and, after a few quiet seconds,
writes "no data for 12 s" beside the bar (cleared when data comes again)."""

from __future__ import annotations

import threading
import time
from types import TracebackType
from typing import Any

QUIET_S = 3.0
"""Seconds without data before the bar says so."""


class StallNote:
    """``with StallNote(bar): ...`` around a download; call :meth:`moved` on each chunk."""

    def __init__(self, bar: Any, *, quiet_s: float = QUIET_S, every_s: float = 1.0) -> None:
        self.bar = bar
        self.quiet_s = quiet_s
        self.every_s = every_s
        self._last = time.monotonic()
        self._shown = False
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._watch, name="stall-note", daemon=True)

    def moved(self) -> None:
        """Data arrived: note the time, and clear the note if one is shown."""
        with self._lock:
            self._last = time.monotonic()
            if self._shown:
                self._shown = False
                self.bar.set_postfix_str("")

    def _watch(self) -> None:
        while not self._stop.wait(self.every_s):
            with self._lock:
                quiet = time.monotonic() - self._last
                if quiet >= self.quiet_s:
                    self._shown = True
                    self.bar.set_postfix_str(f"no data for {quiet:.0f} s")

    def __enter__(self) -> StallNote:
        self._last = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
