"""The study server's state: one SQLite database in the study folder, behind this module only.

``<study>/server/state.sqlite`` (WAL, ``synchronous=FULL``). Every SQL statement of the
server lives here, so another database could be added later behind the same methods.

Tables (schema version :data:`SCHEMA_VERSION`, reached by the migrations in
:data:`MIGRATIONS`, applied in order inside one transaction each; a fresh database runs them
all, so every migration is exercised by every test):

``meta``: ``schema`` (the version number), ``format`` and ``dashboard_logout_ms`` (when the
    dashboard was last logged out of: cookies issued before it open nothing).
``versions``: each manifest the server has served (sha256, study id, the manifest's bytes so a
    participant pinned to an older version can still be served it, registration time, current).
``participants``: id, sha256 of the token (never the token), invitation time, last seen, the
    last client address, the clock offset taken at the last handshake.
``sessions``: one per participant: the session id, the manifest sha256 it is pinned to, the
    acknowledged sequence number and chain head, ratings so far of planned, finish time.
``entries``: the received outbox entries, append-only (the one exception: ``withdraw``), each
    with the client's time of the change and the server's receive time (UTC).
``flags``: what the experimenter should look at, per participant (deduplicated: count, first
    and last time).
``tombstones``: a withdrawn participant's id, when, how much was deleted, and the sha256 of
    their token (so that only they are told they withdrew; nothing else).
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from session_store.errors import StudyError
from session_store.run_lock import lock_path_for
from session_store.sqlite_errors import roll_back
from session_store.study_folder import SERVER_STATE_DIR, SERVER_STATE_FILE

FORMAT = "cgvq-server"
STATE_DIR = SERVER_STATE_DIR
STATE_FILE = SERVER_STATE_FILE


def _script(con: sqlite3.Connection, sql: str) -> None:
    """Run statements one by one (``executescript`` would commit the open transaction)."""
    for stmt in sql.split(";"):
        if stmt.strip():
            con.execute(stmt)


def _v1(con: sqlite3.Connection) -> None:
    """The first schema."""
    _script(con, """
        CREATE TABLE versions (
            manifest_sha256 TEXT PRIMARY KEY, study_id TEXT NOT NULL, manifest BLOB NOT NULL,
            registered_at TEXT NOT NULL, is_current INTEGER NOT NULL DEFAULT 0);
        CREATE TABLE participants (
            participant TEXT PRIMARY KEY, token_sha256 TEXT NOT NULL, invited_at TEXT NOT NULL,
            last_seen TEXT, clock_offset_ms REAL);
        CREATE TABLE sessions (
            session_id TEXT PRIMARY KEY,
            participant TEXT NOT NULL UNIQUE REFERENCES participants(participant),
            manifest_sha256 TEXT NOT NULL REFERENCES versions(manifest_sha256),
            app_version TEXT, created_at TEXT, first_received TEXT NOT NULL,
            last_received TEXT NOT NULL, acked_seq INTEGER NOT NULL, head_hash TEXT NOT NULL,
            n_ratings INTEGER NOT NULL DEFAULT 0, n_planned INTEGER NOT NULL DEFAULT 0,
            finished_at TEXT, closed_as TEXT);
        CREATE TABLE entries (
            session_id TEXT NOT NULL REFERENCES sessions(session_id), seq INTEGER NOT NULL,
            kind TEXT NOT NULL, body TEXT NOT NULL, prev_hash TEXT NOT NULL,
            entry_hash TEXT NOT NULL, client_at TEXT, received_at TEXT NOT NULL,
            PRIMARY KEY (session_id, seq)) WITHOUT ROWID;
        CREATE TABLE flags (
            id INTEGER PRIMARY KEY AUTOINCREMENT, participant TEXT NOT NULL, session_id TEXT,
            kind TEXT NOT NULL, message TEXT NOT NULL, at TEXT NOT NULL);
    """)


def _v2(con: sqlite3.Connection) -> None:
    """Flags are deduplicated (a client retrying a refused upload raises one flag with a
    count), the last client address is kept for abuse checks, withdrawals leave a tombstone."""
    _script(con, """
        ALTER TABLE participants ADD COLUMN last_address TEXT;
        ALTER TABLE flags ADD COLUMN count INTEGER NOT NULL DEFAULT 1;
        ALTER TABLE flags ADD COLUMN last_at TEXT;
        UPDATE flags SET last_at = at;
        CREATE UNIQUE INDEX flags_once ON flags (participant, kind, message);
        CREATE TABLE tombstones (
            participant TEXT PRIMARY KEY, withdrawn_at TEXT NOT NULL,
            entries_deleted INTEGER NOT NULL, reason TEXT NOT NULL);
        CREATE INDEX entries_kind ON entries (kind, session_id);
    """)


def _v3(con: sqlite3.Connection) -> None:
    """The log of adaptive allocation: every refit (which ratings it used) and every block
    issued (with the fit and the pending counts it was planned from), for audit and replay;
    and the DMOS interval widths per number of raters, for the stopping rule."""
    _script(con, """
        CREATE TABLE allocation_fits (
            fit_id INTEGER PRIMARY KEY, at TEXT NOT NULL, used TEXT NOT NULL,
            fit TEXT NOT NULL, seconds REAL NOT NULL);
        CREATE TABLE allocation_blocks (
            session_id TEXT NOT NULL, block INTEGER NOT NULL, block_id TEXT NOT NULL,
            participant TEXT NOT NULL, issued_at TEXT NOT NULL, fit_id INTEGER,
            inputs TEXT NOT NULL, stimuli TEXT NOT NULL, seconds REAL NOT NULL,
            PRIMARY KEY (session_id, block)) WITHOUT ROWID;
        CREATE TABLE stopping_history (
            raters INTEGER PRIMARY KEY, ratings INTEGER NOT NULL, mean_width REAL NOT NULL,
            max_width REAL NOT NULL, at TEXT NOT NULL);
    """)


def _v4(con: sqlite3.Connection) -> None:
    """A tombstone keeps the sha256 of the withdrawn participant's token, so that only
    they learn that they withdrew: for anybody else the id answers as a wrong token does
    (ids are sequential, and withdrawing is personal)."""
    _script(con, "ALTER TABLE tombstones ADD COLUMN token_sha256 TEXT;")


MIGRATIONS: tuple[Callable[[sqlite3.Connection], None], ...] = (_v1, _v2, _v3, _v4)
"""``MIGRATIONS[i]`` takes the database from version ``i`` to ``i + 1``."""
SCHEMA_VERSION = len(MIGRATIONS)
MAX_FLAGS = 100
"""Distinct flags kept per participant (see :meth:`ServerStore.add_flag`)."""


@dataclass(frozen=True)
class Version:
    manifest_sha256: str
    study_id: str
    registered_at: str
    is_current: bool


@dataclass(frozen=True)
class Participant:
    participant: str
    token_sha256: str
    invited_at: str
    last_seen: str | None
    clock_offset_ms: float | None
    last_address: str | None


@dataclass(frozen=True)
class SessionRow:
    session_id: str
    participant: str
    manifest_sha256: str
    app_version: str | None
    created_at: str | None
    first_received: str
    last_received: str
    acked_seq: int
    head_hash: str
    n_ratings: int
    n_planned: int
    finished_at: str | None
    closed_as: str | None


@dataclass(frozen=True)
class StoredEntry:
    seq: int
    kind: str
    body: str
    """The body's canonical JSON text, as received."""
    prev_hash: str
    entry_hash: str
    client_at: str | None
    received_at: str


@dataclass(frozen=True)
class Flag:
    participant: str
    session_id: str | None
    kind: str
    message: str
    first_at: str
    last_at: str
    count: int


@dataclass(frozen=True)
class Tombstone:
    participant: str
    withdrawn_at: str
    entries_deleted: int
    reason: str
    token_sha256: str | None = None  # None: withdrawn before schema version 4

def state_path(study_folder: str | Path) -> Path:
    return Path(study_folder) / STATE_DIR / STATE_FILE


def private_dir(path: Path) -> Path:
    """``path`` as a folder only its owner can enter (0700): it holds personal data."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    with contextlib.suppress(PermissionError):  # another user's folder: leave it as it is
        path.chmod(0o700)
    return path


def private_file(path: Path) -> Path:
    """``path`` created (empty) or tightened to 0600 before SQLite opens it; SQLite gives
    its ``-wal`` and ``-shm`` files the database file's mode."""
    fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o600)
    os.close(fd)
    with contextlib.suppress(PermissionError):
        path.chmod(0o600)
    return path


def _connect(path: Path) -> sqlite3.Connection:
    con = sqlite3.connect(str(path), isolation_level=None, check_same_thread=False, timeout=30)
    con.row_factory = sqlite3.Row
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA synchronous=FULL")
    con.execute("PRAGMA fullfsync=ON")  # macOS: through the drive's cache (as session files)
    con.execute("PRAGMA checkpoint_fullfsync=ON")
    con.execute("PRAGMA foreign_keys=ON")
    con.execute("PRAGMA busy_timeout=30000")
    con.execute("PRAGMA secure_delete=ON")  # withdrawn data is overwritten, not just freed
    return con


def schema_version(con: sqlite3.Connection) -> int:
    exists = con.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name='meta'"
                         ).fetchone()
    if not exists:
        return 0
    row = con.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
    try:
        return int(row[0]) if row else 0
    except (TypeError, ValueError):  # another program's meta table (a session file's)
        return -1


def migrate(con: sqlite3.Connection, path: Path, target: int = SCHEMA_VERSION) -> int:
    """Bring the database to version ``target``, one transaction per step; returns the
    version found before. A newer database than this toolkit knows is refused."""
    con.execute("BEGIN IMMEDIATE")
    try:
        found = schema_version(con)
        if found < 0:
            raise StudyError(f"{path} is not a study-server database; move it away")
        if found == 0:
            tables = con.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
            if tables:
                raise StudyError(f"{path} is not a study-server database; move it away")
            con.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
            con.execute("INSERT INTO meta VALUES ('format', ?), ('schema', '0')", (FORMAT,))
        elif con.execute("SELECT value FROM meta WHERE key='format'").fetchone()[0] != FORMAT:
            raise StudyError(f"{path} is not a study-server database; move it away")
        if found > SCHEMA_VERSION:
            raise StudyError(
                f"{path} has server schema version {found}, newer than this toolkit's "
                f"{SCHEMA_VERSION}: upgrade the toolkit (or serve from a backup made for it)")
        con.execute("COMMIT")
    except BaseException:
        roll_back(con)
        raise
    for version in range(found, target):
        con.execute("BEGIN IMMEDIATE")
        try:
            if schema_version(con) != version:  # another process migrated meanwhile
                con.execute("ROLLBACK")
                continue
            MIGRATIONS[version](con)
            con.execute("UPDATE meta SET value=? WHERE key='schema'", (str(version + 1),))
            con.execute("COMMIT")
        except BaseException:
            roll_back(con)
            raise
    return found


def _refuse_a_lost_database(path: Path) -> None:
    """A missing or empty database beside what a served study leaves (the admin token,
    backups, the database's own -wal) was lost or half restored: starting a new, empty one
    would turn every invited participant away for good."""
    if (path.parent.name, path.name) != (STATE_DIR, STATE_FILE) or (
            path.is_file() and path.stat().st_size > 0):
        return
    own = {path.name, lock_path_for(path).name}
    left = sorted(p.name for p in path.parent.iterdir()  # a Finder's .DS_Store is no trace
                  if p.name not in own and not p.name.startswith(".")) \
        if path.parent.is_dir() else []
    if left:
        state = "is empty" if path.exists() else "is missing"
        raise StudyError(
            f"{path} {state}, but this study was served before ({', '.join(left[:3])} "
            f"{'is' if len(left) == 1 else 'are'} there): restore the database from a backup "
            "(docs: Restoring a backup), or move the folder away to start the study anew")


class ServerStore:
    """The server's database (see the module doc). Thread-safe: one connection per thread,
    writes serialised by a lock (SQLite allows one writer anyway)."""

    def __init__(self, path: str | Path, *, create: bool = True,
                 target_version: int = SCHEMA_VERSION) -> None:
        self.path = Path(path)
        if not self.path.exists() and not create:
            raise StudyError(f"no study-server database at {self.path}: run "
                             "'cgvq-study serve' or 'cgvq-study invite' on the study first")
        _refuse_a_lost_database(self.path)
        if not self.path.parent.exists() or self.path.parent.name == STATE_DIR:
            private_dir(self.path.parent)
        private_file(self.path)
        self._local = threading.local()
        self._write_lock = threading.RLock()
        self._all: list[sqlite3.Connection] = []
        try:
            self.found_version = migrate(self._con(), self.path, target_version)
        except sqlite3.DatabaseError as exc:
            self.close()
            raise StudyError(f"{self.path} is not a readable SQLite database ({exc})") from None
        except BaseException:
            self.close()
            raise

    # -- connections ------------------------------------------------------------------
    def _con(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None:
            con = _connect(self.path)
            self._local.con = con
            self._all.append(con)
        return con

    def close(self) -> None:
        for con in self._all:
            with contextlib.suppress(sqlite3.Error):
                con.close()
        self._all.clear()
        self._local = threading.local()

    def __enter__(self) -> ServerStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        with self._write_lock:
            con = self._con()
            con.execute("BEGIN IMMEDIATE")
            try:
                yield con
                con.execute("COMMIT")
            except BaseException:
                roll_back(con)
                raise

    @contextlib.contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        con = self._con()
        con.execute("BEGIN")
        try:
            yield con
        finally:
            con.execute("COMMIT")

    def writing(self) -> contextlib.AbstractContextManager[sqlite3.Connection]:
        """One write transaction (for the tables other modules own: the allocation log)."""
        return self._write()

    def reading(self) -> contextlib.AbstractContextManager[sqlite3.Connection]:
        """One consistent read."""
        return self._read()

    @property
    def schema_version(self) -> int:
        with self._read() as con:
            return schema_version(con)

    # -- study versions ---------------------------------------------------------------
    def versions(self) -> list[Version]:
        with self._read() as con:
            return [Version(r["manifest_sha256"], r["study_id"], r["registered_at"],
                            bool(r["is_current"]))
                    for r in con.execute("SELECT * FROM versions ORDER BY registered_at")]

    def version_manifest(self, sha: str) -> bytes | None:
        with self._read() as con:
            row = con.execute("SELECT manifest FROM versions WHERE manifest_sha256=?",
                              (sha,)).fetchone()
        return None if row is None else bytes(row[0])

    def sessions_on_other_versions(self, sha: str) -> int:
        with self._read() as con:
            return int(con.execute("SELECT count(*) FROM sessions WHERE manifest_sha256 != ?",
                                   (sha,)).fetchone()[0])

    def set_current_version(self, sha: str, study_id: str, manifest: bytes, at: str) -> None:
        with self._write() as con:
            con.execute("UPDATE versions SET is_current=0")
            con.execute(
                "INSERT INTO versions (manifest_sha256, study_id, manifest, registered_at, "
                "is_current) VALUES (?,?,?,?,1) ON CONFLICT(manifest_sha256) DO UPDATE SET "
                "is_current=1", (sha, study_id, manifest, at))

    # -- participants -----------------------------------------------------------------
    def add_participants(self, rows: Sequence[tuple[str, str]], at: str) -> None:
        """Add (participant, token sha256) pairs; an id in use or withdrawn is refused and
        nothing is added."""
        with self._write() as con:
            for pid, _ in rows:
                if con.execute("SELECT 1 FROM participants WHERE participant=? UNION "
                               "SELECT 1 FROM tombstones WHERE participant=?",
                               (pid, pid)).fetchone():
                    raise StudyError(f"participant {pid} exists already (or withdrew); choose "
                                     "another --prefix")
            con.executemany("INSERT INTO participants (participant, token_sha256, invited_at) "
                            "VALUES (?,?,?)", [(p, t, at) for p, t in rows])

    def participant_ids(self) -> list[str]:
        with self._read() as con:
            return [r[0] for r in con.execute(
                "SELECT participant FROM participants UNION SELECT participant FROM tombstones")]

    def participant(self, pid: str) -> Participant | None:
        with self._read() as con:
            row = con.execute("SELECT * FROM participants WHERE participant=?", (pid,)
                              ).fetchone()
        return None if row is None else _participant(row)

    def participants(self) -> list[Participant]:
        with self._read() as con:
            return [_participant(r) for r in
                    con.execute("SELECT * FROM participants ORDER BY participant")]

    def tombstone(self, pid: str) -> Tombstone | None:
        with self._read() as con:
            row = con.execute("SELECT * FROM tombstones WHERE participant=?", (pid,)).fetchone()
        return None if row is None else Tombstone(*tuple(row))

    def tombstones(self) -> list[Tombstone]:
        with self._read() as con:
            return [Tombstone(*tuple(r)) for r in
                    con.execute("SELECT * FROM tombstones ORDER BY participant")]

    def touch(self, pid: str, at: str, address: str | None,
              clock_offset_ms: float | None = None) -> None:
        with self._write() as con:
            con.execute("UPDATE participants SET last_seen=?, last_address=?, "
                        "clock_offset_ms=coalesce(?, clock_offset_ms) WHERE participant=?",
                        (at, address, clock_offset_ms, pid))

    # -- sessions and entries ---------------------------------------------------------
    def session_of(self, pid: str) -> SessionRow | None:
        with self._read() as con:
            row = con.execute("SELECT * FROM sessions WHERE participant=?", (pid,)).fetchone()
        return None if row is None else SessionRow(**dict(row))

    def sessions(self) -> list[SessionRow]:
        with self._read() as con:
            return [SessionRow(**dict(r)) for r in
                    con.execute("SELECT * FROM sessions ORDER BY participant")]

    def last_events(self) -> dict[str, str]:
        """Per session whose last stored change is a session event, that event's kind
        ("quit": the participant stopped, to continue later)."""
        with self._read() as con:
            rows = con.execute(
                "SELECT s.session_id, e.body FROM sessions s JOIN entries e ON "
                "e.session_id = s.session_id AND e.seq = s.acked_seq WHERE e.kind = 'event'"
            ).fetchall()
        out = {}
        for session_id, body in rows:
            try:
                kind = json.loads(body).get("kind")
            except (ValueError, AttributeError):
                continue
            if isinstance(kind, str):
                out[str(session_id)] = kind
        return out

    def entries(self, session_id: str, after: int = 0, limit: int | None = None
                ) -> list[StoredEntry]:
        sql = ("SELECT seq, kind, body, prev_hash, entry_hash, client_at, received_at FROM "
               "entries WHERE session_id=? AND seq>? ORDER BY seq")
        args: tuple[Any, ...] = (session_id, after)
        if limit is not None:
            sql += " LIMIT ?"
            args += (limit,)
        with self._read() as con:
            return [StoredEntry(*tuple(r)) for r in con.execute(sql, args)]

    def entry_hashes(self, session_id: str) -> list[str]:
        with self._read() as con:
            return [r[0] for r in con.execute(
                "SELECT entry_hash FROM entries WHERE session_id=? ORDER BY seq", (session_id,))]

    def entries_of_kinds(self, kinds: Sequence[str]
                         ) -> list[tuple[str, str, str, str, str]]:
        """(participant, manifest sha256, kind, body, session id) of every entry of these
        kinds, in session and sequence order (the live statistics' and the allocation's
        input). Participants who withdrew in the app are left out, as the analysis leaves
        them out: their consent is withdrawn, and their ratings must not decide a stop."""
        marks = ",".join("?" * len(kinds))
        with self._read() as con:
            return [tuple(r) for r in con.execute(
                "SELECT s.participant, s.manifest_sha256, e.kind, e.body, s.session_id "
                "FROM entries e JOIN "
                f"sessions s USING (session_id) WHERE e.kind IN ({marks}) "
                "AND s.participant NOT IN (SELECT participant FROM sessions "
                "WHERE closed_as = 'withdrawn') "
                "ORDER BY s.participant, e.seq", tuple(kinds))]

    def store_entries(self, *, participant: str, session_id: str,
                      entries: Sequence[StoredEntry], state: dict[str, Any],
                      new_session: dict[str, Any] | None = None,
                      address: str | None = None) -> None:
        """Append received entries, update the session's summary and the participant's last
        contact, in one transaction. ``new_session`` (manifest_sha256, app_version,
        created_at) creates the session row."""
        if not entries:
            return
        last = entries[-1]
        with self._write() as con:
            con.execute("UPDATE participants SET last_seen=?, last_address=? WHERE "
                        "participant=?", (last.received_at, address, participant))
            if new_session is not None:
                con.execute(
                    "INSERT INTO sessions (session_id, participant, manifest_sha256, app_version,"
                    " created_at, first_received, last_received, acked_seq, head_hash) VALUES "
                    "(?,?,?,?,?,?,?,0,'')",
                    (session_id, participant, new_session["manifest_sha256"],
                     new_session["app_version"], new_session["created_at"],
                     last.received_at, last.received_at))
            row = con.execute("SELECT acked_seq FROM sessions WHERE session_id=?",
                              (session_id,)).fetchone()
            if row is None or int(row[0]) + 1 != entries[0].seq:
                raise StudyError("the stored session moved on meanwhile; send again")
            con.executemany(
                "INSERT INTO entries (session_id, seq, kind, body, prev_hash, entry_hash, "
                "client_at, received_at) VALUES (?,?,?,?,?,?,?,?)",
                [(session_id, e.seq, e.kind, e.body, e.prev_hash, e.entry_hash, e.client_at,
                  e.received_at) for e in entries])
            con.execute(
                "UPDATE sessions SET acked_seq=?, head_hash=?, last_received=?, n_ratings=?, "
                "n_planned=?, finished_at=?, closed_as=? WHERE session_id=?",
                (last.seq, last.entry_hash, last.received_at, state["n_ratings"],
                 state["n_planned"], state["finished_at"], state["closed_as"], session_id))

    # -- flags ------------------------------------------------------------------------
    def add_flag(self, participant: str, session_id: str | None, kind: str, message: str,
                 at: str) -> bool:
        """Record a flag (a repeat only counts up); True when it is a new one. A
        participant's distinct flags stop at :data:`MAX_FLAGS` (their texts come from the
        client's behaviour, so a client could otherwise add rows without end); later ones
        count up one ``too_many_flags`` row. A participant who has withdrawn gets none: a
        withdrawal that lands between an upload and its flag must leave nothing behind."""
        message = message[:500]
        with self._write() as con:
            if con.execute("SELECT 1 FROM tombstones WHERE participant=?", (participant,)
                           ).fetchone():  # withdrawn between the upload and its flag
                return False
            known = con.execute("SELECT 1 FROM flags WHERE participant=? AND kind=? AND "
                                "message=?", (participant, kind, message)).fetchone()
            if known is None:
                (n,) = con.execute("SELECT COUNT(*) FROM flags WHERE participant=?",
                                   (participant,)).fetchone()
                if n >= MAX_FLAGS:
                    kind, message = "too_many_flags", (
                        f"more than {MAX_FLAGS} distinct flags; later ones are only counted "
                        "here")
            con.execute(
                "INSERT INTO flags (participant, session_id, kind, message, at, last_at) "
                "VALUES (?,?,?,?,?,?) ON CONFLICT(participant, kind, message) DO UPDATE SET "
                "count=count+1, last_at=excluded.last_at", (participant, session_id, kind,
                                                            message, at, at))
        return known is None and kind != "too_many_flags"

    def flags(self, participant: str | None = None) -> list[Flag]:
        sql = ("SELECT participant, session_id, kind, message, at, last_at, count FROM flags"
               + (" WHERE participant=?" if participant else "") + " ORDER BY id")
        with self._read() as con:
            return [Flag(*tuple(r)) for r in con.execute(sql, (participant,) if participant
                                                         else ())]

    # -- operations -------------------------------------------------------------------
    def withdraw(self, pid: str, at: str, reason: str) -> Tombstone:
        """Delete everything of a participant and keep a tombstone (the one exception to
        append-only storage)."""
        with self._write() as con:
            known = con.execute("SELECT 1 FROM participants WHERE participant=?", (pid,)
                                ).fetchone()
            if not known:
                if con.execute("SELECT 1 FROM tombstones WHERE participant=?", (pid,)
                               ).fetchone():
                    raise StudyError(f"participant {pid} has withdrawn already")
                raise StudyError(f"participant {pid} is not invited to this study")
            n = int(con.execute(
                "SELECT count(*) FROM entries WHERE session_id IN (SELECT session_id FROM "
                "sessions WHERE participant=?)", (pid,)).fetchone()[0])
            con.execute("DELETE FROM entries WHERE session_id IN (SELECT session_id FROM "
                        "sessions WHERE participant=?)", (pid,))
            con.execute("DELETE FROM sessions WHERE participant=?", (pid,))
            con.execute("DELETE FROM flags WHERE participant=?", (pid,))
            con.execute("DELETE FROM allocation_blocks WHERE participant=?", (pid,))
            (token_sha256,) = con.execute("SELECT token_sha256 FROM participants WHERE "
                                          "participant=?", (pid,)).fetchone()
            con.execute("DELETE FROM participants WHERE participant=?", (pid,))
            con.execute("INSERT INTO tombstones VALUES (?,?,?,?,?)",
                        (pid, at, n, reason, token_sha256))
        return Tombstone(pid, at, n, reason, token_sha256)

    def backup(self, dest: str | Path) -> Path:
        """An online copy (SQLite's backup API: consistent while the server writes)."""
        dest = Path(dest)
        if dest.exists():
            raise StudyError(f"{dest} exists already; choose another backup file")
        if not dest.parent.exists():
            private_dir(dest.parent)
        tmp = dest.with_name(dest.name + ".partial")
        try:
            tmp.unlink(missing_ok=True)
            out = sqlite3.connect(str(private_file(tmp)))
        except (OSError, sqlite3.Error) as exc:
            raise StudyError(f"cannot write the backup {dest}: {exc}") from None
        try:
            try:
                self._con().backup(out, pages=256)
                check = out.execute("PRAGMA integrity_check").fetchone()[0]
            finally:
                out.close()
            if check != "ok":
                raise StudyError(f"the backup failed its integrity check: {check}")
            tmp.replace(dest)
        except BaseException as exc:
            tmp.unlink(missing_ok=True)  # a partial copy of personal data is not kept
            if isinstance(exc, (OSError, sqlite3.Error)):
                raise StudyError(f"cannot write the backup {dest} ({exc}; is the disk "
                                 "full?); nothing was kept") from None
            raise
        return dest

    def record_widths(self, raters: int, ratings: int, mean_width: float, max_width: float,
                      at: str) -> None:
        """The DMOS interval widths with ``raters`` raters in (the latest per count). Points
        with more raters are dropped: they were computed on ratings that are gone now (a
        withdrawal, or raters the screening now removes), and the decay must not be fitted
        on them."""
        with self._write() as con:
            con.execute("DELETE FROM stopping_history WHERE raters > ?", (raters,))
            con.execute("INSERT OR REPLACE INTO stopping_history VALUES (?,?,?,?,?)",
                        (raters, ratings, mean_width, max_width, at))

    def width_history(self) -> list[tuple[int, int, float, float]]:
        with self._read() as con:
            return [tuple(r) for r in con.execute(
                "SELECT raters, ratings, mean_width, max_width FROM stopping_history "
                "ORDER BY raters")]

    def ratings_received_since(self, since: str) -> list[tuple[str | None, float | None]]:
        """The ratings that arrived since ``since``: each one's time on the participant's
        clock and that clock's offset from the server's (ms, server minus participant)."""
        with self._read() as con:
            return [(r[0], r[1]) for r in con.execute(
                "SELECT e.client_at, p.clock_offset_ms FROM entries e "
                "JOIN sessions s ON s.session_id = e.session_id "
                "JOIN participants p ON p.participant = s.participant "
                "WHERE e.kind='rating' AND e.received_at >= ?", (since,))]

    def checkpoint(self) -> bool:
        """Fold the WAL into the main file and truncate it; False when a reader held it."""
        try:
            busy = self._con().execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0]
        except sqlite3.Error:
            return False
        return busy == 0

    def dashboard_logout_ms(self) -> int:
        """When the dashboard was last logged out of (epoch ms; 0: never)."""
        with self._read() as con:
            row = con.execute("SELECT value FROM meta WHERE key='dashboard_logout_ms'"
                              ).fetchone()
        return int(row[0]) if row is not None else 0

    def record_dashboard_logout(self, at_ms: int) -> None:
        with self._write() as con:
            con.execute("INSERT INTO meta VALUES ('dashboard_logout_ms', ?) ON CONFLICT(key) "
                        "DO UPDATE SET value=excluded.value", (str(at_ms),))

    def change_marker(self) -> tuple[int, ...]:
        """Changes when entries, flags, tombstones or invitations change (cheap; for the
        statistics: ``invite`` beside a running server changes the target per stimulus)."""
        with self._read() as con:
            row = con.execute(
                "SELECT (SELECT count(*) FROM entries), (SELECT coalesce(sum(count), 0) FROM "
                "flags), (SELECT count(*) FROM tombstones), (SELECT count(*) FROM "
                "participants)").fetchone()
        return tuple(int(v) for v in row)


def _participant(row: sqlite3.Row) -> Participant:
    return Participant(row["participant"], row["token_sha256"], row["invited_at"],
                       row["last_seen"], row["clock_offset_ms"], row["last_address"])
