"""The outbox: an ordered, hash-chained log of every change made to a session file.

Every write of :class:`~session_store.writer.SessionStore` (the session's creation with
its plan, pre-flight, start, consent and other events, each rating with its presentation
log, re-queues, finish, withdrawal) is applied through :mod:`.mutations` *and* appended here,
in the same transaction. The log is what the upload client sends to a study server, entry by
entry with its sequence number and chain hash; the server replays it (the same mutations) to
hold a copy of the file that the participant cannot rewrite afterwards. It also covers what
the rating chain does not (pre-flight results, display, vsync, dropped-frame counts,
settings), and lets a reader check that a file's tables are what its log says.

``entry_hash = sha256(prev_hash + canonical({"seq", "kind", "body"}))``; the first entry's
``prev_hash`` is ``sha256("cgvq-outbox/1" + NUL + session_id)``.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from .chain import canonical, sha256_text

OUTBOX_FORMAT = "cgvq-outbox/1"

OUTBOX_DDL = """
CREATE TABLE IF NOT EXISTS outbox (
    seq INTEGER PRIMARY KEY, kind TEXT NOT NULL, body TEXT NOT NULL,
    prev_hash TEXT NOT NULL, entry_hash TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS upload_state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


@dataclass(frozen=True)
class OutboxEntry:
    """One change of a session file, as uploaded."""

    seq: int
    kind: str
    body: dict[str, Any]
    prev_hash: str
    entry_hash: str

    def as_json(self) -> dict[str, Any]:
        return {"seq": self.seq, "kind": self.kind, "body": self.body,
                "prev_hash": self.prev_hash, "entry_hash": self.entry_hash}


def outbox_genesis(session_id: str) -> str:
    return sha256_text(f"{OUTBOX_FORMAT}\0{session_id}")


def entry_hash(prev_hash: str, seq: int, kind: str, body: dict[str, Any]) -> str:
    return sha256_text(prev_hash + canonical({"seq": seq, "kind": kind, "body": body}))


def has_outbox(con: sqlite3.Connection) -> bool:
    return con.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND name='outbox'"
                       ).fetchone() is not None


def append(con: sqlite3.Connection, kind: str, body: dict[str, Any], session_id: str
           ) -> OutboxEntry:
    """Append one entry (inside the caller's transaction)."""
    last = con.execute("SELECT seq, entry_hash FROM outbox ORDER BY seq DESC LIMIT 1").fetchone()
    seq, prev = (1, outbox_genesis(session_id)) if last is None else (last[0] + 1, last[1])
    digest = entry_hash(prev, seq, kind, body)
    con.execute("INSERT INTO outbox (seq, kind, body, prev_hash, entry_hash) VALUES (?,?,?,?,?)",
                (seq, kind, canonical(body), prev, digest))
    return OutboxEntry(seq, kind, body, prev, digest)


def insert_verbatim(con: sqlite3.Connection, entry: OutboxEntry) -> None:
    """Store a received entry as it is (replay on the server)."""
    con.execute("INSERT INTO outbox (seq, kind, body, prev_hash, entry_hash) VALUES (?,?,?,?,?)",
                (entry.seq, entry.kind, canonical(entry.body), entry.prev_hash,
                 entry.entry_hash))


def read_entries(con: sqlite3.Connection, after: int = 0, limit: int | None = None
                 ) -> list[OutboxEntry]:
    """Stored entries with ``seq > after`` in order (the stored hashes, not re-checked)."""
    sql = "SELECT * FROM outbox WHERE seq > ? ORDER BY seq"
    args: tuple[Any, ...] = (after,)
    if limit is not None:
        sql += " LIMIT ?"
        args = (after, limit)
    return [OutboxEntry(r["seq"], r["kind"], _body(r["body"]), r["prev_hash"],
                        r["entry_hash"]) for r in con.execute(sql, args)]


def _body(text: str) -> dict[str, Any]:
    """An entry's body; one that is not a JSON object (a damaged file) is a ValueError."""
    body = json.loads(text)
    if not isinstance(body, dict):
        raise ValueError(f"an outbox entry's body is {type(body).__name__}, not an object")
    return body


def chain_problem(entries: Iterable[OutboxEntry], session_id: str, *,
                  start_seq: int = 1, start_hash: str | None = None) -> str | None:
    """Why the entries do not form the chain (recomputed from their content), or None."""
    prev = start_hash if start_hash is not None else outbox_genesis(session_id)
    expected = start_seq
    for e in entries:
        if e.seq != expected:
            return f"entry {e.seq} where {expected} was expected"
        if e.prev_hash != prev:
            return f"entry {e.seq} does not follow entry {e.seq - 1}"
        if entry_hash(prev, e.seq, e.kind, e.body) != e.entry_hash:
            return f"entry {e.seq}'s content does not match its hash"
        prev, expected = e.entry_hash, expected + 1
    return None


def acked_seq(con: sqlite3.Connection) -> int:
    """Highest sequence number a study server has acknowledged (0: none)."""
    if not has_outbox(con):
        return 0
    row = con.execute("SELECT value FROM upload_state WHERE key='acked_seq'").fetchone()
    return int(row[0]) if row else 0


def set_upload_state(con: sqlite3.Connection, key: str, value: str) -> None:
    con.execute("INSERT INTO upload_state (key, value) VALUES (?, ?) "
                "ON CONFLICT(key) DO UPDATE SET value=excluded.value", (key, value))
