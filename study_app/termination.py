"""A request from outside to end the run (the system shutting down or logging out, the
terminal closed, Ctrl+C in it): taken as the participant's confirmed "stop and continue later".

Without this, SDL turns SIGTERM into a window-close event, which asks the participant to
confirm; nobody answers during a shutdown, the system kills the app, and the session ends
with no "quit" recorded and the last answers not sent. SIGINT raised ``KeyboardInterrupt``
wherever the app happened to be, and SIGHUP (a closed terminal) killed it outright.

The handler only notes the signal and posts a window-close event (it runs between two
bytecodes of the main thread, so it must not stop the app halfway through storing a rating);
the app's event loops turn that event into the confirmed quit at their next poll."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from types import FrameType

#: The signals that mean "end this run"; SIGHUP only where the system has it.
SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGINT", "SIGHUP")
                if hasattr(signal, name))


class Termination:
    """Which signal asked the run to end, if any (``name`` is e.g. "SIGTERM")."""

    def __init__(self) -> None:
        self.name: str | None = None

    @property
    def requested(self) -> bool:
        return self.name is not None


@contextlib.contextmanager
def termination_watch(on_signal: Callable[[], None]) -> Iterator[Termination]:
    """While inside, SIGTERM/SIGINT/SIGHUP set the yielded :class:`Termination` and call
    ``on_signal`` (which posts the window-close event); the previous handlers come back on
    exit, so a second signal while the last answers are being sent ends the process as
    before. Outside the main thread (tests calling the app from a worker) nothing is
    installed."""
    seen = Termination()

    def handler(signum: int, _frame: FrameType | None) -> None:
        seen.name = signal.Signals(signum).name
        on_signal()

    previous = {}
    try:
        for sig in SIGNALS:
            try:
                previous[sig] = signal.signal(sig, handler)
            except ValueError:  # not the main thread
                break
        yield seen
    finally:
        for sig, old in previous.items():
            signal.signal(sig, signal.SIG_DFL if old is None else old)
