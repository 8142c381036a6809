"""One holder at a time of a file: an exclusive OS lock on a file beside it. One run per
participant (session files), one server per study (its database), one writer per scores CSV.

The lock is an OS file lock (``fcntl.flock`` on POSIX, ``msvcrt.locking`` on Windows), held
by an open file descriptor, so the OS releases it when the process ends in any way (crash,
SIGKILL, power loss). A lock file left behind by a dead process is therefore not "held": the
next holder simply takes it over. The lock file records the holder's pid and start time for
the refusal message, and is removed when the holder ends normally.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .errors import LockedError, ToolkitError

LOCK_SUFFIX = ".lock"


def lock_path_for(path: Path) -> Path:
    """``P01.sqlite`` -> ``P01.sqlite.lock`` (beside it)."""
    return path.with_name(path.name + LOCK_SUFFIX)


def _try_lock(fd: int) -> bool:
    if sys.platform == "win32":
        import msvcrt

        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _unlock(fd: int) -> None:
    if sys.platform == "win32":
        import msvcrt

        with contextlib.suppress(OSError):
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
    else:
        import fcntl

        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)


def read_holder(path: Path) -> dict[str, Any]:
    """What a lock file says about its holder (empty when unreadable)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


class FileLock:
    """Exclusive lock beside one file, held for a process's life; use as a context manager
    or call :meth:`acquire` / :meth:`release`."""

    error: type[ToolkitError] = LockedError
    """What a refusal raises (a package's own error type in a subclass)."""

    def __init__(self, path: Path, owner: str, *, busy: Callable[[str], str]) -> None:
        """``owner`` is written into the lock file (a participant id, ``server``, ...);
        ``busy(holder)`` words the refusal (``holder``: ' (process N since T)' or '')."""
        self.path = lock_path_for(Path(path))
        self.owner = owner
        self._busy = busy
        self._fd: int | None = None
        self.took_over: dict[str, Any] | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> FileLock:
        """Take the lock or raise :attr:`error` naming the process that holds it (an error of
        the file system, such as a full disk, names the lock file)."""
        try:
            return self._acquire()
        except OSError as exc:
            if exc.filename is not None:
                raise
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None

    def _acquire(self) -> FileLock:
        for _ in range(10):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            if not _try_lock(fd):
                os.close(fd)
                holder = read_holder(self.path)
                since = f" since {holder['since']}" if holder.get("since") else ""
                pid = f" (process {holder['pid']}{since})" if holder.get("pid") else ""
                raise self.error(self._busy(pid))
            # The file may have been removed by a run that just ended: lock the file that is
            # on disk now, not an unlinked one.
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(self.path))
            except FileNotFoundError:
                same = False
            if not same:
                _unlock(fd)
                os.close(fd)
                continue
            previous = read_holder(self.path)
            if previous.get("pid"):
                self.took_over = previous
            self._fd = fd
            self._write_holder()
            return self
        raise self.error(f"could not lock {self.path}: it keeps changing; try again")

    def _write_holder(self) -> None:
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "since": datetime.now(UTC).isoformat(timespec="seconds"),
                "owner": self.owner}
        data = json.dumps(info).encode()
        assert self._fd is not None
        os.ftruncate(self._fd, 0)
        os.lseek(self._fd, 0, os.SEEK_SET)
        os.write(self._fd, data)
        os.fsync(self._fd)

    def release(self) -> None:
        """Remove the lock file and release the lock (idempotent)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        if sys.platform != "win32":
            # Unlink while still holding the lock, so no other run can lock the old inode
            # after we let go (acquire re-checks that its file is the one on disk).
            with contextlib.suppress(OSError):
                self.path.unlink()
        _unlock(fd)
        os.close(fd)
        if sys.platform == "win32":
            with contextlib.suppress(OSError):
                self.path.unlink()

    def __enter__(self) -> FileLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
