"""A session file rebuilt from its outbox: the study server's copy, and the local self-check.

:class:`Replica` holds the file a server builds from the entries it received: each batch is
checked against the chain (sequence continuity, hashes recomputed from content) and applied
through the same :mod:`.mutations` as the participant's app, so the copy is a regular session
file that ``verify`` and the analysis read. Entries already held are compared: a re-send of
the same entry is accepted silently (idempotent); a different entry under an acknowledged
sequence number is a :class:`ContradictionError`, and nothing of that batch is stored.

:func:`tables_match_outbox` replays a file's own outbox into memory and compares the result
with the file's tables, so an edit that bypassed the app (in tables the rating chain does not
cover, too) shows up.
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from .errors import StudyError
from .mutations import apply as apply_change
from .mutations import create_tables
from .outbox import (
    OutboxEntry,
    chain_problem,
    entry_hash,
    has_outbox,
    insert_verbatim,
    outbox_genesis,
    read_entries,
)
from .schema import DAMAGE_ERRORS, connect, has_table, open_existing
from .sqlite_errors import roll_back


class ContradictionError(StudyError):
    """A received entry contradicts one already acknowledged (edited, removed, reordered)."""


def _check_batch(entries: Sequence[OutboxEntry], start_seq: int, start_hash: str,
                 session_id: str) -> None:
    problem = chain_problem(entries, session_id, start_seq=start_seq,
                            start_hash=start_hash)
    if problem:
        raise StudyError(f"upload refused: {problem}")


class Replica:
    """A session file built only from received outbox entries."""

    def __init__(self, con: sqlite3.Connection, path: Path | None) -> None:
        self._con = con
        self.path = path

    @classmethod
    def create(cls, path: str | Path, first: OutboxEntry) -> Replica:
        """A new replica from the session's first entry (its header and plan)."""
        path = Path(path)
        if path.exists():
            raise StudyError(f"{path} exists already")
        if first.seq != 1 or first.kind != "session":
            raise StudyError("upload refused: a session starts with its 'session' entry (seq 1)")
        session_id = str(first.body.get("header", {}).get("session_id", ""))
        _check_batch([first], 1, outbox_genesis(session_id), session_id)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".creating")
        tmp.unlink(missing_ok=True)
        con = connect(tmp, readonly=False)
        try:
            con.execute("BEGIN IMMEDIATE")
            create_tables(con)
            apply_change(con, "session", first.body)
            insert_verbatim(con, first)
            con.execute("COMMIT")
            con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            con.close()
        tmp.replace(path)
        return cls.open(path)

    @classmethod
    def in_memory(cls, first: OutboxEntry) -> Replica:
        """A replica held in memory only (a study server's working copy, rebuilt from its
        database after a restart); ``path`` is None."""
        if first.seq != 1 or first.kind != "session":
            raise StudyError("upload refused: a session starts with its 'session' entry (seq 1)")
        session_id = str(first.body.get("header", {}).get("session_id", ""))
        _check_batch([first], 1, outbox_genesis(session_id), session_id)
        con = sqlite3.connect(":memory:", isolation_level=None, check_same_thread=False)
        con.row_factory = sqlite3.Row
        con.execute("PRAGMA foreign_keys=ON")
        con.execute("BEGIN")
        try:
            create_tables(con)
            apply_change(con, "session", first.body)
            insert_verbatim(con, first)
        except BaseException:
            roll_back(con)
            con.close()
            raise
        con.execute("COMMIT")
        return cls(con, None)

    @classmethod
    def open(cls, path: str | Path) -> Replica:
        path = Path(path)
        return cls(open_existing(path, readonly=False), path)

    def close(self) -> None:
        try:
            if self.path is not None:
                self._con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            self._con.close()

    def __enter__(self) -> Replica:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def session_id(self) -> str:
        return str(self._con.execute("SELECT session_id FROM session").fetchone()[0])

    def head(self) -> tuple[int, str]:
        """(last stored sequence number, its entry hash)."""
        row = self._con.execute(
            "SELECT seq, entry_hash FROM outbox ORDER BY seq DESC LIMIT 1").fetchone()
        return (int(row[0]), str(row[1])) if row else (0, outbox_genesis(self.session_id))

    def summary(self) -> dict[str, Any]:
        """Ratings so far, distinct trials planned, finish time and how the session closed
        (``finish`` or ``withdrawn``); inside :meth:`staged`, including the staged entries."""
        con = self._con
        row = con.execute("SELECT n_ratings, finished_at FROM session").fetchone()
        planned = con.execute(
            "SELECT count(*) FROM (SELECT DISTINCT stimulus, repetition FROM plan)").fetchone()[0]
        closed = con.execute("SELECT kind FROM events WHERE kind IN ('finish', 'withdrawn') "
                             "ORDER BY id DESC LIMIT 1").fetchone()
        return {"n_ratings": int(row[0]), "n_planned": int(planned), "finished_at": row[1],
                "closed_as": closed[0] if closed else None}

    def entry_hash_at(self, seq: int) -> str | None:
        row = self._con.execute("SELECT entry_hash FROM outbox WHERE seq=?", (seq,)).fetchone()
        return None if row is None else str(row[0])

    def fresh_entries(self, entries: Sequence[OutboxEntry]) -> list[OutboxEntry]:
        """The entries of a batch not held yet, after checking the held ones against what is
        stored: a re-sent entry must be the acknowledged one, its hash recomputed from its
        content (a body changed under the old hash is a contradiction too). Raises
        :class:`ContradictionError`, or :class:`StudyError` when the new entries do not
        continue the chain."""
        entries = sorted(entries, key=lambda e: e.seq)
        if len({e.seq for e in entries}) != len(entries):
            raise StudyError("upload refused: the batch holds a sequence number twice")
        head_seq, head_hash = self.head()
        fresh = []
        for e in entries:
            if e.seq < 1:
                raise StudyError(f"upload refused: sequence number {e.seq} is not positive")
            if e.seq <= head_seq:
                held = self._con.execute("SELECT prev_hash, entry_hash FROM outbox WHERE seq=?",
                                         (e.seq,)).fetchone()
                same = (held is not None and held[1] == e.entry_hash and held[0] == e.prev_hash
                        and entry_hash(e.prev_hash, e.seq, e.kind, e.body) == e.entry_hash)
                if not same:
                    raise ContradictionError(
                        f"entry {e.seq} ({e.kind}) differs from the acknowledged one: the "
                        "session file was changed after upload")
            else:
                fresh.append(e)
        if fresh:
            _check_batch(fresh, head_seq + 1, head_hash, self.session_id)
        return fresh

    @contextlib.contextmanager
    def staged(self, entries: Sequence[OutboxEntry]) -> Iterator[list[OutboxEntry]]:
        """Apply a batch's new entries in an open transaction and yield them; the transaction
        commits when the block ends normally and rolls back when it raises. A server stores
        the entries in its own database inside the block, so the replica never runs ahead of
        what was durably acknowledged. Raises like :meth:`fresh_entries`, or
        :class:`StudyError` when an entry does not fit the session (a rating out of order,
        a forged row hash...); nothing of a refused batch is kept."""
        fresh = self.fresh_entries(entries)
        if not fresh:
            yield []
            return
        self._con.execute("BEGIN IMMEDIATE")
        try:
            for e in fresh:
                apply_change(self._con, e.kind, e.body)
                insert_verbatim(self._con, e)
            yield fresh
            self._con.execute("COMMIT")
        except BaseException:
            roll_back(self._con)
            raise

    def accept(self, entries: Sequence[OutboxEntry]) -> int:
        """Store the new entries of a batch (all or nothing); returns the acknowledged
        sequence number. Raises :class:`ContradictionError` when an entry contradicts a
        stored one, :class:`StudyError` when the batch does not continue the chain or does
        not fit the session (a rating out of order, a forged row hash...)."""
        with self.staged(entries):
            pass
        return self.head()[0]


def _dump(con: sqlite3.Connection) -> dict[str, list[tuple[Any, ...]]]:
    tables = {
        "session": "SELECT session_id, participant, study_id, manifest_sha256, seed, "
                   "app_version, created_at, settings, display, preflight, preflight_skipped, "
                   "started_at, finished_at, n_ratings, head_hash FROM session",
        "plan": "SELECT * FROM plan ORDER BY idx",
        "ratings": "SELECT * FROM ratings ORDER BY seq",
        "presentations": "SELECT trial, outcome, details, logged_at FROM presentations "
                         "ORDER BY id",
        "events": "SELECT at, kind, details FROM events ORDER BY id",
        "answers": "SELECT questionnaire, question, value, page, ms, answered_at FROM answers "
                   "ORDER BY id",
        "screenings": "SELECT test, outcome, result, at FROM screenings ORDER BY id",
    }
    # a file older than the panel tables has none: the same as empty ones
    return {name: [tuple(r) for r in con.execute(sql)] if has_table(con, name) else []
            for name, sql in tables.items()}


def tables_match_outbox(path: str | Path) -> list[str]:
    """Differences between a session file's tables and the replay of its own outbox
    (empty when they agree). A change log that is missing, or that a damaged file makes
    unreadable, is a difference of its own, never an exception."""
    path = Path(path)
    con = open_existing(path, readonly=True)
    try:
        return _compare_with_log(con)
    except DAMAGE_ERRORS as exc:
        return [f"the change log is unreadable ({_reason(exc)})"]
    finally:
        con.close()


def _reason(exc: BaseException) -> str:
    try:
        return str(exc) or type(exc).__name__
    except ValueError:
        return type(exc).__name__


def _compare_with_log(con: sqlite3.Connection) -> list[str]:
    con.execute("BEGIN")
    try:
        if not has_outbox(con):  # every version of the writer creates it with the file
            return ["the change log (outbox) is missing: every session file is written with "
                    "one, so it was removed outside the app"]
        entries = read_entries(con)
        actual = _dump(con)
    finally:
        con.execute("COMMIT")
    if not entries:
        return ["the outbox is empty"]
    session_id = str(entries[0].body.get("header", {}).get("session_id", ""))
    problem = chain_problem(entries, session_id)
    if problem:
        return [f"the change log is broken: {problem}"]
    mem = sqlite3.connect(":memory:", isolation_level=None)
    mem.row_factory = sqlite3.Row
    try:
        mem.execute("BEGIN")
        create_tables(mem)
        for e in entries:
            apply_change(mem, e.kind, e.body)
        mem.execute("COMMIT")
        expected = _dump(mem)
    except (StudyError, sqlite3.Error) as exc:
        return [f"the change log does not replay: {exc}"]
    finally:
        mem.close()
    return [f"table {name} differs from the change log (edited outside the app)"
            for name in expected if expected[name] != actual[name]]
