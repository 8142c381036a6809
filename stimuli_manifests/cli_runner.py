"""The one runner of the toolkit's CLIs: user errors become one line on stderr and exit 2.

``cgvq-study``, ``cgvq-analyze`` and ``cgvqm`` parse their arguments, then call
:func:`run_command` with the work to do. Anything derived from :class:`ToolkitError`, an
optional library that is not installed, or an operating-system error on a path the user gave
(a folder where a file was expected, a name too long, no permission) is printed as
``<prog>: error: <message>`` on one line; Ctrl-C exits 130 (and, where the command asks,
SIGTERM from a job scheduler or ``timeout`` exits 143 with the same message). Programming errors
still raise.
"""

from __future__ import annotations

import argparse
import errno
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NoReturn

from .errors import ToolkitError
from .extras import explain_missing

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 128 + signal.SIGTERM


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C's KeyboardInterrupt would be, so the same clean-up runs."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated


@contextmanager
def _sigterm_raises() -> Iterator[None]:
    """SIGTERM raises :class:`Terminated` inside (main thread only; a handler someone else
    installed is left alone)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def one_line(message: object) -> str:
    """The message folded onto one line (newlines and runs of blanks become one space)."""
    return " ".join(str(message).split())


class OneLineParser(argparse.ArgumentParser):
    """argparse's parser, but a usage error is one line on stderr (exit 2) like every other
    user error, pointing at ``--help`` rather than printing the usage block. Subcommand
    parsers made by :meth:`add_subparsers` are of this class too."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)",
              file=sys.stderr)
        sys.exit(EXIT_USER_ERROR)


#: what to do about the operating-system errors a user can fix, by errno
_OS_ADVICE = {
    errno.ENOSPC: "the disk is full: free some space on it and run the same command again",
    errno.EDQUOT: "your disk quota is used up: free some space and run the same command again",
    errno.EROFS: "that disk or folder is read-only (a zip opened in place, a CD, a read-only "
                 "share?): copy the files to a folder you can write to and run from there",
    errno.EACCES: "you may not use that file or folder: check its permissions, or use a "
                  "folder of your own",
}


def _os_error_text(exc: OSError) -> str:
    reason = exc.strerror or str(exc)
    if exc.filename is not None:
        target = exc.filename if exc.filename2 is None else f"{exc.filename} -> {exc.filename2}"
        reason = f"{reason}: {target}"
    advice = _OS_ADVICE.get(exc.errno) if exc.errno is not None else None
    return f"{reason} ({advice})" if advice else reason


def run_command(prog: str, work: Callable[[], int], *, extra: str | None = None,
                interrupted: str = "interrupted", sigterm_interrupts: bool = False) -> int:
    """Run ``work`` and return its exit code, or 2 / 130 (143) as described in the module
    doc. ``sigterm_interrupts``: SIGTERM ends the work as Ctrl-C does, said, not silently."""
    try:
        if sigterm_interrupts:
            with _sigterm_raises():
                return int(work())
        return int(work())
    except ToolkitError as exc:
        message = one_line(exc)
    except ModuleNotFoundError as exc:
        missing = explain_missing(exc, what="this command", extra=extra)
        if missing is None:
            raise
        message = one_line(missing)
    except OSError as exc:
        message = one_line(_os_error_text(exc))
    except Terminated:
        print(f"{prog}: stopped by SIGTERM: {interrupted}", file=sys.stderr)
        return EXIT_TERMINATED
    except KeyboardInterrupt:
        print(f"{prog}: {interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"{prog}: error: {message}", file=sys.stderr)
    return EXIT_USER_ERROR
