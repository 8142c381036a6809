"""The session file's schema (``cgvq-session/1``) and how a file is opened.

Tables
------
``meta(key TEXT PRIMARY KEY, value TEXT)``
    ``schema`` = :data:`SCHEMA_VERSION`. A file whose major version differs is refused.
``session`` (exactly one row)
    ``session_id, participant, study_id, manifest_sha256, seed, app_version, created_at``
    (these and the original plan form the *genesis* of the hash chain), ``settings`` (JSON:
    protocol values in force, timing mode), ``display`` (JSON: screen, refresh rate, vsync),
    ``preflight`` (JSON: list of check results), ``preflight_skipped`` (0/1), ``started_at``,
    ``finished_at`` (NULL while open), ``n_ratings`` and ``head_hash`` (the last rating row's
    hash, updated in the same transaction as the row: a removed tail is detected).
``plan(idx INTEGER PRIMARY KEY, stimulus, reference, repetition, is_hidden_reference, requeue_of)``
    The trial order, stored before the first trial. ``requeue_of`` is NULL for planned trials
    and names the superseded trial for a trial re-queued (at the end) after too many dropped
    frames. In an adaptive study the later blocks are appended when the plan so far is
    answered (a ``block`` event records each: number, id, issuer, first index, size); the
    chain's genesis covers the first block, each rating row names its stimulus.
``ratings`` (one row per answered trial, ``trial`` unique)
    ``seq`` (1, 2, ... in answer order), ``trial`` (the plan index), the stimulus and what was
    measured (see :data:`CHAINED`), ``prev_hash``, ``row_hash`` (see :mod:`.chain`).
``presentations(id, trial, outcome, details JSON, logged_at)``
    Per trial attempt: flip-timing summary, toggles, switch latencies; ``outcome`` is
    ``rated`` or ``requeued``.
``events(id, at, kind, details JSON)``
    Session events (created, consent, start, resume, pause, pre-flight, quit, withdrawn,
    finish).
``answers(id, questionnaire, question, value JSON, page, ms, answered_at)``
    Every answer confirmed in a questionnaire of the manifest's panel block, in order; a
    question answered again (the participant went back) has several rows, the last counts.
``screenings(id, test, outcome, result JSON, at)``
    Results of the optional vision checks (``outcome``: passed, failed, inconclusive).
    Files written before these two tables existed lack them and hold no answers.

SQLite runs in WAL mode with ``synchronous=FULL``; every rating is one committed transaction,
checkpointed into the main file right after, so the ``.sqlite`` file alone holds every
committed rating even when the process was killed before it could close.
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from pathlib import Path

from stimuli_manifests.formats import FormatVersionError, VersionedFormat

from .errors import StudyError

SESSION_FORMAT = VersionedFormat("cgvq-session", 1, field="session schema")
SCHEMA_NAME = SESSION_FORMAT.name
SCHEMA_MAJOR = SESSION_FORMAT.major
SCHEMA_VERSION = SESSION_FORMAT.version

# Columns of the ratings table covered by the hash (everything except row_hash itself).
CHAINED = (
    "seq",
    "trial",
    "stimulus",
    "reference",
    "repetition",
    "is_hidden_reference",
    "rating",
    "rt_ms",
    "n_toggles",
    "ms_on_reference",
    "ms_on_test",
    "slider_first_move_ms",
    "frames_presented",
    "dropped_frames",
    "max_flip_interval_ms",
    "switch_latencies_ms",
    "presented_at",
    "answered_at",
    "app_version",
    "prev_hash",
)
INT_COLUMNS = frozenset({
    "seq", "trial", "repetition", "is_hidden_reference", "n_toggles", "frames_presented",
    "dropped_frames",
})
REAL_COLUMNS = frozenset({
    "rating", "rt_ms", "ms_on_reference", "ms_on_test", "slider_first_move_ms",
    "max_flip_interval_ms",
})

DDL = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE session (
    session_id TEXT NOT NULL, participant TEXT NOT NULL, study_id TEXT NOT NULL,
    manifest_sha256 TEXT, seed INTEGER NOT NULL, app_version TEXT NOT NULL,
    created_at TEXT NOT NULL, settings TEXT NOT NULL DEFAULT '{}',
    display TEXT NOT NULL DEFAULT '{}', preflight TEXT NOT NULL DEFAULT '[]',
    preflight_skipped INTEGER NOT NULL DEFAULT 0, started_at TEXT, finished_at TEXT,
    n_ratings INTEGER NOT NULL DEFAULT 0, head_hash TEXT NOT NULL
);
CREATE TABLE plan (
    idx INTEGER PRIMARY KEY, stimulus TEXT NOT NULL, reference TEXT NOT NULL,
    repetition INTEGER NOT NULL, is_hidden_reference INTEGER NOT NULL,
    requeue_of INTEGER REFERENCES plan(idx)
);
CREATE TABLE ratings (
    seq INTEGER PRIMARY KEY, trial INTEGER NOT NULL UNIQUE REFERENCES plan(idx),
    stimulus TEXT NOT NULL, reference TEXT NOT NULL, repetition INTEGER NOT NULL,
    is_hidden_reference INTEGER NOT NULL, rating REAL NOT NULL, rt_ms REAL NOT NULL,
    n_toggles INTEGER NOT NULL, ms_on_reference REAL NOT NULL, ms_on_test REAL NOT NULL,
    slider_first_move_ms REAL, frames_presented INTEGER NOT NULL,
    dropped_frames INTEGER NOT NULL, max_flip_interval_ms REAL NOT NULL,
    switch_latencies_ms TEXT NOT NULL, presented_at TEXT NOT NULL, answered_at TEXT NOT NULL,
    app_version TEXT NOT NULL, prev_hash TEXT NOT NULL, row_hash TEXT NOT NULL
);
CREATE TABLE presentations (
    id INTEGER PRIMARY KEY AUTOINCREMENT, trial INTEGER NOT NULL, outcome TEXT NOT NULL,
    details TEXT NOT NULL, logged_at TEXT NOT NULL
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, at TEXT NOT NULL, kind TEXT NOT NULL,
    details TEXT NOT NULL DEFAULT '{}'
);
"""


# Added within cgvq-session/1 (a file without them simply holds no answers): created with
# every new file and when an older file is opened for writing.
PANEL_DDL = """
CREATE TABLE IF NOT EXISTS answers (
    id INTEGER PRIMARY KEY AUTOINCREMENT, questionnaire TEXT NOT NULL, question TEXT NOT NULL,
    value TEXT NOT NULL, page INTEGER NOT NULL, ms REAL, answered_at TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS screenings (
    id INTEGER PRIMARY KEY AUTOINCREMENT, test TEXT NOT NULL, outcome TEXT NOT NULL,
    result TEXT NOT NULL, at TEXT NOT NULL
);
"""
SCREENING_OUTCOMES = ("passed", "failed", "inconclusive")


def has_table(con: sqlite3.Connection, name: str) -> bool:
    """Whether the file has table ``name`` (the panel tables are missing in older files)."""
    return con.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?",
                       (name,)).fetchone() is not None


#: what reading a damaged session file can raise besides :class:`StudyError`: SQLite's own
#: errors, text that is not UTF-8 or JSON (ValueError), rows missing fields (KeyError,
#: TypeError, IndexError), numbers out of range (OverflowError), nesting too deep
DAMAGE_ERRORS: tuple[type[BaseException], ...] = (
    sqlite3.Error, ValueError, KeyError, TypeError, IndexError, OverflowError, RecursionError)


def _tolerant_text(data: bytes) -> str:
    """Text columns of a damaged file decode with U+FFFD instead of failing the read, so
    the damage shows up as a hash mismatch (a problem in the report), never a crash."""
    return data.decode("utf-8", "replace")


def _sidecars(path: Path) -> tuple[Path, Path]:
    return Path(f"{path}-wal"), Path(f"{path}-shm")


def _remove_empty_sidecars(path: Path) -> None:
    """Remove the empty ``-wal`` and ``-shm`` a read-only reader made beside a file that had
    none, so reading a folder of returned sessions leaves it as it was. SQLite removes them
    itself when the last connection that may write closes: a brief such connection does
    it (``query_only``: nothing is written, the main file keeps its bytes). A writer that
    has the file open keeps them, and one that wrote meanwhile is left alone."""
    wal, _ = _sidecars(path)
    try:
        if wal.stat().st_size != 0:
            return
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=rw", uri=True,
                              isolation_level=None)
        try:
            con.execute("PRAGMA query_only=ON")
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        finally:
            con.close()
    except (OSError, sqlite3.Error):
        pass


class _TidyReader(sqlite3.Connection):
    """A read-only connection that, on close, removes the sidecar files it made."""

    tidy_path: Path | None = None

    def close(self) -> None:
        super().close()
        path, self.tidy_path = self.tidy_path, None
        if path is not None:
            _remove_empty_sidecars(path)


def _open_read_only(path: Path) -> sqlite3.Connection:
    """A read-only connection that sees the WAL; raises OperationalError where the folder
    cannot be written (SQLite then cannot make the ``-shm`` it needs to read the WAL).
    Sidecar files it has to make are removed again when it closes."""
    had_sidecars = any(side.exists() for side in _sidecars(path))
    con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, isolation_level=None,
                          factory=_TidyReader)
    if not had_sidecars:
        con.tidy_path = path
    try:
        con.execute("SELECT count(*) FROM sqlite_master").fetchone()
    except BaseException:
        con.close()
        raise
    return con


def _folded_copy(path: Path) -> sqlite3.Connection:
    """The file with its ``-wal`` folded in, held in memory: what a read-only folder (a USB
    stick, a read-only share) holds, read in full. The two files are copied to a private
    temporary folder, read there (SQLite replays the WAL), and copied into memory."""
    with tempfile.TemporaryDirectory(prefix="cgvq-readonly-") as tmp:
        copy = Path(tmp) / path.name
        shutil.copyfile(path, copy)
        shutil.copyfile(f"{path}-wal", f"{copy}-wal")
        disk = sqlite3.connect(str(copy), isolation_level=None)
        mem = sqlite3.connect(":memory:", isolation_level=None)
        try:
            disk.backup(mem)
        except BaseException:
            mem.close()
            raise
        finally:
            disk.close()
    mem.execute("PRAGMA query_only=ON")
    return mem


def connect(path: Path, *, readonly: bool) -> sqlite3.Connection:
    """A connection in autocommit mode (transactions are explicit).

    Read-only connections see the WAL (committed ratings not yet checkpointed). Where the
    folder cannot be written (a read-only medium) SQLite cannot read a WAL in place: the file
    and its ``-wal`` are then read from a private copy (see :func:`_folded_copy`), and a file
    without a ``-wal`` is opened as immutable. Text that is not UTF-8 is read with U+FFFD.
    """
    if readonly:
        try:
            con = _open_read_only(path)
        except sqlite3.OperationalError:
            if wal_pending_bytes(path) > 0:
                try:
                    con = _folded_copy(path)
                except OSError as exc:
                    raise StudyError(
                        f"{path.name}-wal beside {path} cannot be read from this folder "
                        f"({exc}); copy both files ({path.name} and {path.name}-wal) to a "
                        "folder you can write to and try again") from None
            else:
                con = sqlite3.connect(f"{path.resolve().as_uri()}?immutable=1", uri=True,
                                      isolation_level=None)
        con.text_factory = _tolerant_text
    else:
        con = sqlite3.connect(str(path), isolation_level=None)
        con.execute("PRAGMA journal_mode=WAL")
        con.execute("PRAGMA synchronous=FULL")
        # On macOS fsync() leaves the data in the drive's cache, where a power cut loses
        # it; F_FULLFSYNC (these two) reaches the platter. Elsewhere they change nothing.
        con.execute("PRAGMA fullfsync=ON")
        con.execute("PRAGMA checkpoint_fullfsync=ON")
        con.execute("PRAGMA foreign_keys=ON")
    con.row_factory = sqlite3.Row
    return con


def check_schema(con: sqlite3.Connection, path: Path) -> None:
    """Refuse files that are not session files or have another major schema version."""
    try:
        row = con.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
    except (sqlite3.DatabaseError, ValueError):
        raise StudyError(
            f"{path} is not a cgvq-study session file (no session schema found); pass the "
            "<participant>.sqlite file written by 'cgvq-study run' or 'simulate'"
        ) from None
    if row is None:
        raise StudyError(f"{path} is not a cgvq-study session file (schema version missing)")
    try:
        SESSION_FORMAT.check(str(row[0]))
    except FormatVersionError as exc:
        raise StudyError(f"{path}: {exc}") from None


def open_existing(path: str | Path, *, readonly: bool) -> sqlite3.Connection:
    """Open a session file after checking it exists and has the right schema; a file that
    cannot be read as one is a :class:`StudyError` (with a hint when its ``-wal`` is
    missing: a full disk can leave the main file readable only together with it)."""
    path = Path(path)
    if not path.is_file():
        raise StudyError(f"session file not found: {path}")
    try:
        con = connect(path, readonly=readonly)
    except DAMAGE_ERRORS as exc:
        raise StudyError(unreadable_message(path, exc)) from None
    try:
        check_schema(con, path)
    except StudyError:
        con.close()
        raise
    except DAMAGE_ERRORS as exc:
        con.close()
        raise StudyError(unreadable_message(path, exc)) from None
    return con


def unreadable_message(path: Path, exc: BaseException) -> str:
    """Why ``path`` is not a readable session file; when no ``-wal`` lies beside it, the
    hint to ask for one (the main file of a session interrupted by a full disk is
    readable only with its ``-wal``)."""
    text = f"{path} is not a readable SQLite session file ({_reason(exc)})"
    if wal_pending_bytes(path) == 0:
        text += (f"; if {path.name}-wal was beside it where it was written, ask for that "
                 "file too and put it next to this one (after a full disk the file is "
                 "readable only together with it)")
    return text


def _reason(exc: BaseException) -> str:
    """The error's text, or its type when even that is damaged."""
    try:
        return str(exc) or type(exc).__name__
    except ValueError:
        return type(exc).__name__


def wal_pending_bytes(path: str | Path) -> int:
    """Size of a ``-wal`` file beside ``path`` (0 when none): committed data that may not be
    in the main file yet. A file sent back without it can lack ratings."""
    wal = Path(f"{path}-wal")
    try:
        return wal.stat().st_size
    except OSError:
        return 0
