"""What a failed SQLite call means, and undoing its transaction: shared by the session files
and the study server's database, which meet the same full disks and busy readers."""

from __future__ import annotations

import contextlib
import errno
import sqlite3

_BUSY_CODES = (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED)
_IO_CODES = (sqlite3.SQLITE_IOERR, sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_READONLY)


def _primary_code(exc: BaseException) -> int | None:
    """SQLite's primary result code (the extended code's low byte), where Python gives it."""
    code = getattr(exc, "sqlite_errorcode", None)
    return None if code is None else code & 0xFF


def is_busy(exc: sqlite3.Error) -> bool:
    """Whether ``exc`` only means another connection holds the file for now (retry later),
    not that writing failed (a full disk, an I/O error)."""
    code = _primary_code(exc)
    if code is None:
        return "locked" in str(exc) or "busy" in str(exc)
    return code in _BUSY_CODES


def is_disk_full(exc: BaseException) -> bool:
    """The disk (or the quota) is full: SQLite's SQLITE_FULL, or ENOSPC/EDQUOT from a file."""
    if isinstance(exc, sqlite3.Error):
        return _primary_code(exc) == sqlite3.SQLITE_FULL
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def is_io_error(exc: sqlite3.Error) -> bool:
    """The file could not be written or opened at all (not a busy reader, not a full disk)."""
    return _primary_code(exc) in _IO_CODES


def roll_back(con: sqlite3.Connection) -> None:
    """Undo a failed transaction if SQLite has not already. After a full disk or an I/O error
    it rolls back by itself, and a second ROLLBACK would replace the real error with its own;
    a failed COMMIT leaves the transaction open, and every later BEGIN would then fail."""
    if con.in_transaction:
        with contextlib.suppress(sqlite3.Error):
            con.execute("ROLLBACK")
