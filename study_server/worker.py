"""A background thread that redoes one piece of work when poked, at most every N seconds
(the dashboard's statistics, the allocation's refit): requests only poke it, never wait."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from session_store.sqlite_errors import is_disk_full

log = logging.getLogger(__name__)

REST_FACTOR = 2.0
"""The dashboard's statistics rest at least this many times as long as their last run took:
statistics that grow with the study (seconds at thousands of ratings) keep within a third of
one core instead of following each other back to back. (The allocation's refit does not
rest: the blocks participants ask for wait on it.)"""


class ThrottledWorker:
    """Runs ``work`` after :meth:`poke` (or every ``every_s`` anyway), never more often than
    every ``every_s`` seconds nor sooner than ``rest_factor`` times its last duration after
    it ended; an exception is logged and handed to ``on_error``, and the
    thread goes on. ``before`` runs once on the thread first (imports, warm-up)."""

    def __init__(self, name: str, every_s: float, work: Callable[[], object], *,
                 on_error: Callable[[Exception], None] | None = None,
                 before: Callable[[], None] | None = None, join_s: float = 60.0,
                 rest_factor: float = 0.0) -> None:
        self.name = name
        self.every_s = every_s
        self.work = work
        self.on_error = on_error
        self.before = before
        self.join_s = join_s
        self.rest_factor = rest_factor
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last = 0.0
        self._took = 0.0

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=self.join_s)

    def poke(self) -> None:
        self._wake.set()

    def _run(self) -> None:
        if self.before is not None:
            self.before()
        while not self._stop.is_set():
            wait = self._last + max(self.every_s, self.rest_factor * self._took) - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                break
            self._wake.wait(timeout=self.every_s)
            self._wake.clear()
            if self._stop.is_set():
                break
            started = time.monotonic()
            try:
                self.work()
            except Exception as exc:  # the server keeps serving
                if is_disk_full(exc):  # one line: it fails again at every turn until space is freed
                    log.error("%s failed: the disk of the study folder is full (%s)",
                              self.name, exc)
                else:
                    log.exception("%s failed", self.name)
                if self.on_error is not None:
                    self.on_error(exc)
            self._last = time.monotonic()
            self._took = self._last - started
